#include "kernels/table_gradient.h"

#include <algorithm>
#include <cmath>

#include "kernels/cpu_parallel.h"
#include "kernels/hash_grid.h"
#include "kernels/hash_grid_cpu.h"

#ifdef ABLENERF_HAVE_AVX2_FORM
#include <immintrin.h>
#endif

namespace ablenerf {

namespace table_gradient_impl {

thread_local int t_key = -1;

// Entries per thread of the finishing pass, below which a second thread does not pay.
constexpr int64_t kEntriesPerWorker = 1 << 16;

// What the finishing pass reads and writes: out = sum + two_decay x w.
struct FinishArgs {
  const float* sum;
  const float* w;
  float two_decay;
  float* out;
};

// What a range of the finishing pass found: the sum of w^2 over it, and whether every entry it
// wrote is finite (Adam's check of the same gradient then need not read it again).
struct FinishSums {
  double squares = 0.0;
  bool finite = true;
};

// Entries [lo, hi). The finite test is a running sum of out x 0: 0 while every entry is finite,
// NaN from the first infinite or NaN one on.
FinishSums finish_scalar(const FinishArgs& a, int64_t lo, int64_t hi) {
  double sq = 0.0;
  float probe = 0.0f;
  for (int64_t j = lo; j < hi; ++j) {
    a.out[j] = a.sum[j] + a.two_decay * a.w[j];
    probe += a.out[j] * 0.0f;
    sq += static_cast<double>(a.w[j]) * a.w[j];
  }
  return {sq, probe == 0.0f};
}

#ifdef ABLENERF_HAVE_AVX2_FORM
// 16 entries at a time, the same float additions in the same order (no fused multiply-add); the
// squares summed in float64 in 16 lanes (another order of the sum than the scalar loop's).
ABLENERF_TARGET_AVX512 ABLENERF_SEPARATE_ROUNDINGS FinishSums finish_avx512(const FinishArgs& a, int64_t lo,
                                                                            int64_t hi) {
  const __m512 zero = _mm512_setzero_ps(), two_decay = _mm512_set1_ps(a.two_decay);
  __m512d sq_low = _mm512_setzero_pd(), sq_high = _mm512_setzero_pd();
  __m512 probe = zero;
  int64_t j = lo;
  for (; j + 16 <= hi; j += 16) {
    const __m512 w = _mm512_loadu_ps(a.w + j);
    const __m512 out = _mm512_add_ps(_mm512_loadu_ps(a.sum + j), _mm512_mul_ps(two_decay, w));
    _mm512_storeu_ps(a.out + j, out);
    probe = _mm512_add_ps(probe, _mm512_mul_ps(out, zero));
    const __m512d w_low = _mm512_cvtps_pd(_mm512_castps512_ps256(w));
    const __m512d w_high = _mm512_cvtps_pd(_mm512_castps512_ps256(_mm512_shuffle_f32x4(w, w, 0xEE)));
    sq_low = _mm512_add_pd(sq_low, _mm512_mul_pd(w_low, w_low));
    sq_high = _mm512_add_pd(sq_high, _mm512_mul_pd(w_high, w_high));
  }
  alignas(64) double lanes[8];
  _mm512_store_pd(lanes, _mm512_add_pd(sq_low, sq_high));
  double sq = 0.0;
  for (const double lane : lanes) sq += lane;
  const FinishSums tail = finish_scalar(a, j, hi);
  // A NaN lane compares unequal to zero.
  const bool finite = _mm512_cmp_ps_mask(probe, zero, _CMP_NEQ_UQ) == 0;
  return {sq + tail.squares, finite && tail.finite};
}
#endif

FinishSums finish_in(CpuVectorForm form, const FinishArgs& a, int64_t lo, int64_t hi) {
#ifdef ABLENERF_HAVE_AVX2_FORM
  if (form == CpuVectorForm::Avx512) return finish_avx512(a, lo, hi);
#endif
  (void)form;
  return finish_scalar(a, lo, hi);
}

// The levels' sums in level order (the same on any number of threads), finite when every level is.
FinishSums levels_total(const std::vector<FinishSums>& levels) {
  FinishSums total;
  for (const auto& l : levels) {
    total.squares += l.squares;
    total.finite = total.finite && l.finite;
  }
  return total;
}

}  // namespace table_gradient_impl

int TableGradient::current_key() { return table_gradient_impl::t_key; }

TableGradient::TableGradient(const HashGridShape& shape) : shape_(shape) {}

void TableGradient::defer(int k, DeferredLookup lookup) {
  TORCH_CHECK(k >= 0, "TableGradient: key ", k, " is negative");
  const auto& p = lookup.positions;
  const auto& g = lookup.grad_out;
  const auto& sc = lookup.scales;
  const auto ok = [](const torch::Tensor& t) {
    return t.is_cpu() && t.scalar_type() == torch::kFloat && t.is_contiguous();
  };
  TORCH_CHECK(ok(p) && p.dim() == 2 && p.size(1) == 3,
              "TableGradient: positions must be a contiguous float32 CPU (n, 3) tensor, got ", p.sizes());
  const int64_t n = p.size(0);
  TORCH_CHECK(ok(g) && g.dim() == 3 && g.size(0) == n && g.size(1) == shape_.levels && g.size(2) == shape_.features,
              "TableGradient: grad_out must be a contiguous float32 CPU (", n, ", ", shape_.levels, ", ",
              shape_.features, ") tensor, got ", g.sizes());
  TORCH_CHECK(!sc.defined() || (ok(sc) && sc.dim() == 2 && sc.size(0) == n && sc.size(1) == shape_.levels),
              "TableGradient: scales must be a contiguous float32 CPU (", n, ", ", shape_.levels, ") tensor");
  // The sum of the lookup's magnitudes (lookups_finite), on the deferring thread while its values
  // are in its cache: in float, 8 lanes at a time (an infinity or NaN anywhere makes it one too).
  constexpr int64_t kLanes = 8;
  const int64_t rows = n * shape_.levels, features = shape_.features;
  const float* gp = g.data_ptr<float>();
  const float* scale = sc.defined() ? sc.data_ptr<float>() : nullptr;
  const auto row = [&](int64_t r) {
    float total = 0.0f;
    for (int64_t f = 0; f < features; ++f) total += std::abs(gp[r * features + f]);
    return scale != nullptr ? total * std::abs(scale[r]) : total;
  };
  float lanes[kLanes] = {};
  int64_t i = 0;
  for (; i + kLanes <= rows; i += kLanes)
    for (int64_t j = 0; j < kLanes; ++j) lanes[j] += row(i + j);
  for (; i < rows; ++i) lanes[0] += row(i);
  double bound = 0.0;
  for (const float lane : lanes) bound += lane;
  const std::lock_guard<std::mutex> lock(mutex_);
  deferred_.push_back({k, std::move(lookup), bound});
}

bool TableGradient::pending() const {
  const std::lock_guard<std::mutex> lock(mutex_);
  return !deferred_.empty();
}

void TableGradient::discard() {
  const std::lock_guard<std::mutex> lock(mutex_);
  deferred_.clear();
}

void TableGradient::check_parameter(const torch::Tensor& parameter) const {
  TORCH_CHECK(parameter.is_cpu() && parameter.scalar_type() == torch::kFloat && parameter.is_contiguous() &&
                  parameter.dim() == 3 && parameter.size(0) == shape_.levels &&
                  parameter.size(1) == shape_.table_size && parameter.size(2) == shape_.features,
              "TableGradient: the parameter must be a contiguous float32 CPU (", shape_.levels, ", ", shape_.table_size,
              ", ", shape_.features, ") tensor, got ", parameter.sizes());
}

// Each level's gradient from the deferred lookups, the levels dealt out in turn among the threads
// (their lookups cost the same; a dense level's rows are fewer), then done(level, sum, begin, count):
// sum[0, count) the level's entries from `begin` (flat), every entry a lookup can reach (`all`:
// every entry of the level), starting from g0 where given. Each thread sums in a buffer of one
// level that it reuses level after level, so that the buffer stays in its core's cache (a level of
// the capture preset is 512 KiB) while the scatters add to it at random. The lookups in key order,
// each key's in the order they came: the same sums whichever thread deferred first.
template <class Done>
void TableGradient::sum_levels(CpuVectorForm form, const float* g0, bool all, Done&& done) {
  std::stable_sort(deferred_.begin(), deferred_.end(),
                   [](const Deferred& a, const Deferred& b) { return a.key < b.key; });
  const int64_t levels = shape_.levels, features = shape_.features, level_size = shape_.table_size * features;
  int64_t reached = 0;
  for (int l = 0; l < levels; ++l) reached += all ? level_size : hash_grid_level_rows(shape_, l) * features;
  const int64_t workers = std::min<int64_t>(cpu_workers(reached, table_gradient_impl::kEntriesPerWorker), levels);
  std::vector<std::vector<float>> scratch(static_cast<size_t>(workers));
  parallel_slices(workers, workers, [&](int64_t t, int64_t, int64_t) {
    auto& sum = scratch[static_cast<size_t>(t)];
    for (int64_t l = t; l < levels; l += workers) {
      const int level = static_cast<int>(l);
      const int64_t begin = l * level_size;
      const int64_t count = all ? level_size : hash_grid_level_rows(shape_, level) * features;
      if (g0 != nullptr)
        sum.assign(g0 + begin, g0 + begin + count);
      else
        sum.assign(static_cast<size_t>(count), 0.0f);
      for (const auto& entry : deferred_) {
        const DeferredLookup& d = entry.lookup;
        hash_grid_backward_level_cpu_in(form, d.positions.data_ptr<float>(), d.positions.size(0),
                                        d.grad_out.data_ptr<float>(), shape_, level,
                                        d.scales.defined() ? d.scales.data_ptr<float>() : nullptr, sum.data());
      }
      done(level, sum.data(), begin, count);
    }
  });
  deferred_.clear();
}

double TableGradient::finish(torch::Tensor& parameter, double decay, CpuVectorForm form) {
  TORCH_CHECK(cpu_vector_form_available(form), "TableGradient: the AVX-512 form on a CPU without it");
  const std::lock_guard<std::mutex> lock(mutex_);
  finite_ = false;
  if (deferred_.empty() && decay == 0) return 0.0;
  check_parameter(parameter);
  torch::Tensor before = parameter.grad();
  if (before.defined()) before = before.to(torch::kFloat).contiguous();
  // Every entry when a gradient before must be carried over, else the ones a lookup reaches.
  const bool part = !before.defined();
  // The buffer handed out last step is reused unless someone else still holds it (then a new one:
  // never write through a tensor another owner reads), and, for a partial pass, only while it is
  // still 0 outside the reached entries.
  if (!grad_.defined() || !grad_.sizes().equals(parameter.sizes()) || grad_.use_count() > 1 ||
      (before.defined() && before.is_same(grad_)) || (part && !outside_zero_)) {
    grad_ = part ? torch::zeros_like(parameter) : torch::empty_like(parameter);
    outside_zero_ = part;
  }
  if (!part) outside_zero_ = false;
  const float* w = parameter.data_ptr<float>();
  float* out = grad_.data_ptr<float>();
  const float two_decay = static_cast<float>(2 * decay);
  std::vector<table_gradient_impl::FinishSums> sums(static_cast<size_t>(shape_.levels));
  sum_levels(form, before.defined() ? before.data_ptr<float>() : nullptr, !part,
             [&](int level, const float* sum, int64_t begin, int64_t count) {
               sums[static_cast<size_t>(level)] =
                   table_gradient_impl::finish_in(form, {sum, w + begin, two_decay, out + begin}, 0, count);
             });
  parameter.mutable_grad() = grad_;
  const auto total = table_gradient_impl::levels_total(sums);
  finite_ = total.finite;
  return decay * total.squares;
}

bool TableGradient::lookups_finite() const {
  const std::lock_guard<std::mutex> lock(mutex_);
  double bound = 0.0;
  for (const auto& entry : deferred_) bound += entry.bound;
  return std::isfinite(bound) && bound < kLookupBound;
}

double TableGradient::finish_adam(torch::Tensor& parameter, double decay, const AdamScalars& scalars, float* m,
                                  float* v, CpuVectorForm form) {
  TORCH_CHECK(cpu_vector_form_available(form), "TableGradient: the AVX-512 form on a CPU without it");
  const std::lock_guard<std::mutex> lock(mutex_);
  finite_ = false;
  check_parameter(parameter);
  TORCH_CHECK(!parameter.grad().defined(), "TableGradient: finish_adam on a parameter that holds a gradient");
  float* w = parameter.data_ptr<float>();
  const float two_decay = static_cast<float>(2 * decay);
  std::vector<table_gradient_impl::FinishSums> sums(static_cast<size_t>(shape_.levels));
  sum_levels(form, nullptr, false, [&](int level, const float* sum, int64_t begin, int64_t count) {
    auto& out = sums[static_cast<size_t>(level)];
    out.squares =
        adam_update_decayed_cpu_in(form, count, sum, two_decay, m + begin, v + begin, w + begin, scalars, out.finite);
  });
  const auto total = table_gradient_impl::levels_total(sums);
  finite_ = total.finite;
  return decay * total.squares;
}

TableGradientScope::TableGradientScope(int k) : previous_(table_gradient_impl::t_key) {
  table_gradient_impl::t_key = k;
}

TableGradientScope::~TableGradientScope() { table_gradient_impl::t_key = previous_; }

torch::Tensor table_gradient_reference(const torch::Tensor& grad, const std::vector<DeferredLookup>& lookups,
                                       const torch::Tensor& parameter, const HashGridShape& shape, double decay) {
  // In finish()'s order: the gradient before, each lookup's scatter, then the decay's term.
  auto out = grad.defined() ? grad.clone() : torch::zeros_like(parameter);
  for (const auto& d : lookups) {
    const torch::AutoGradMode enable(true);
    auto table = parameter.detach().clone().set_requires_grad(true);
    auto features = hash_grid_encode_reference(d.positions, table, shape);
    if (d.scales.defined()) features = features * d.scales.unsqueeze(-1);
    out = out + torch::autograd::grad({(features * d.grad_out).sum()}, {table})[0];
  }
  out = out + parameter * (2 * decay);
  if (grad.defined()) return out;
  auto reached = torch::zeros({parameter.numel()}, torch::kBool);
  for (const auto& [begin, end] : hash_grid_table_entries(shape)) reached.slice(0, begin, end).fill_(true);
  return out * reached.view(parameter.sizes());
}

}  // namespace ablenerf
