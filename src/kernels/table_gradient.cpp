#include "kernels/table_gradient.h"

#include <algorithm>

#include "kernels/cpu_parallel.h"

#ifdef ABLENERF_HAVE_AVX2_FORM
#include <immintrin.h>
#endif

namespace ablenerf {

namespace table_gradient_impl {

thread_local int t_slot = -1;

// Entries per thread of the finishing pass, below which a second thread does not pay.
constexpr int64_t kEntriesPerWorker = 1 << 16;

// What the finishing pass reads and writes: out = g0 (or 0) + src[0] + ... + two_decay x w, the
// slots zeroed.
struct FinishArgs {
  const float* g0;
  const std::vector<float*>& src;
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
    float g = a.g0 != nullptr ? a.g0[j] : 0.0f;
    for (float* s : a.src) {
      g += s[j];
      s[j] = 0.0f;
    }
    a.out[j] = g + a.two_decay * a.w[j];
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
    __m512 g = a.g0 != nullptr ? _mm512_loadu_ps(a.g0 + j) : zero;
    for (float* s : a.src) {
      g = _mm512_add_ps(g, _mm512_loadu_ps(s + j));
      _mm512_storeu_ps(s + j, zero);
    }
    const __m512 w = _mm512_loadu_ps(a.w + j);
    const __m512 out = _mm512_add_ps(g, _mm512_mul_ps(two_decay, w));
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

}  // namespace table_gradient_impl

int TableGradient::current_slot() { return table_gradient_impl::t_slot; }

float* TableGradient::slot(const torch::Tensor& table, int k) {
  TORCH_CHECK(k >= 0, "TableGradient: slot ", k, " is negative");
  TORCH_CHECK(table.is_cpu() && table.scalar_type() == torch::kFloat && table.is_contiguous(),
              "TableGradient: the table must be a contiguous float32 CPU tensor, got ", table.scalar_type(), " on ",
              table.device());
  const std::lock_guard<std::mutex> lock(mutex_);
  const auto kk = static_cast<size_t>(k);
  if (slots_.size() <= kk) {
    slots_.resize(kk + 1);
    written_.resize(kk + 1, false);
  }
  auto& s = slots_[kk];
  if (!s.defined() || !s.sizes().equals(table.sizes())) s = torch::zeros_like(table);
  written_[kk] = true;
  return s.data_ptr<float>();
}

bool TableGradient::pending() const {
  const std::lock_guard<std::mutex> lock(mutex_);
  return std::find(written_.begin(), written_.end(), true) != written_.end();
}

void TableGradient::discard() {
  const std::lock_guard<std::mutex> lock(mutex_);
  for (size_t k = 0; k < slots_.size(); ++k)
    if (written_[k]) slots_[k].zero_();
  std::fill(written_.begin(), written_.end(), false);
}

double TableGradient::finish(torch::Tensor& parameter, double decay, CpuVectorForm form) {
  TORCH_CHECK(cpu_vector_form_available(form), "TableGradient: the AVX-512 form on a CPU without it");
  const std::lock_guard<std::mutex> lock(mutex_);
  finite_ = false;
  std::vector<float*> src;
  for (size_t k = 0; k < slots_.size(); ++k) {
    if (!written_[k]) continue;
    TORCH_CHECK(slots_[k].sizes().equals(parameter.sizes()), "TableGradient: a slot of ", slots_[k].sizes(),
                " for a parameter of ", parameter.sizes());
    src.push_back(slots_[k].data_ptr<float>());
  }
  if (src.empty() && decay == 0) return 0.0;
  TORCH_CHECK(parameter.is_cpu() && parameter.scalar_type() == torch::kFloat && parameter.is_contiguous(),
              "TableGradient: the parameter must be a contiguous float32 CPU tensor");
  torch::Tensor before = parameter.grad();
  if (before.defined()) before = before.to(torch::kFloat).contiguous();
  const int64_t n = parameter.numel();
  TORCH_CHECK(entries_.empty() || entries_.back().second <= n, "TableGradient: entries up to ", entries_.back().second,
              " for a parameter of ", n);
  // Only the entries lookups reach, unless a gradient before must be carried over everywhere.
  const bool part = !entries_.empty() && !before.defined();
  // The buffer handed out last step is reused unless someone else still holds it (then a new one:
  // never write through a tensor another owner reads), and, for a partial pass, only while it is
  // still 0 outside the entries.
  if (!grad_.defined() || !grad_.sizes().equals(parameter.sizes()) || grad_.use_count() > 1 ||
      (before.defined() && before.is_same(grad_)) || (part && !outside_zero_)) {
    grad_ = part ? torch::zeros_like(parameter) : torch::empty_like(parameter);
    outside_zero_ = part;
  }
  if (!part) outside_zero_ = false;
  const float* w = parameter.data_ptr<float>();
  const float* g0 = before.defined() ? before.data_ptr<float>() : nullptr;
  float* out = grad_.data_ptr<float>();
  const IndexRanges all{{0, n}};
  const IndexRanges& ranges = part ? entries_ : all;
  const float two_decay = static_cast<float>(2 * decay);
  const int64_t workers = cpu_workers(index_count(ranges), table_gradient_impl::kEntriesPerWorker);
  std::vector<table_gradient_impl::FinishSums> sums(static_cast<size_t>(workers));
  const table_gradient_impl::FinishArgs args{g0, src, w, two_decay, out};
  parallel_ranges(ranges, workers, [&](int64_t t, int64_t lo, int64_t hi) {
    const table_gradient_impl::FinishSums piece = table_gradient_impl::finish_in(form, args, lo, hi);
    auto& sum = sums[static_cast<size_t>(t)];
    sum.squares += piece.squares;
    sum.finite = sum.finite && piece.finite;
  });
  std::fill(written_.begin(), written_.end(), false);
  parameter.mutable_grad() = grad_;
  double total = 0.0;
  finite_ = true;
  for (const auto& s : sums) {
    total += s.squares;
    finite_ = finite_ && s.finite;
  }
  return decay * total;
}

void TableGradient::set_entries(IndexRanges entries) {
  for (size_t i = 0; i < entries.size(); ++i)
    TORCH_CHECK(entries[i].first <= entries[i].second && (i == 0 || entries[i - 1].second <= entries[i].first),
                "TableGradient: entry ranges must be sorted and disjoint");
  const std::lock_guard<std::mutex> lock(mutex_);
  entries_ = std::move(entries);
  outside_zero_ = false;
}

TableGradientScope::TableGradientScope(int k) : previous_(table_gradient_impl::t_slot) {
  table_gradient_impl::t_slot = k;
}

TableGradientScope::~TableGradientScope() { table_gradient_impl::t_slot = previous_; }

torch::Tensor table_gradient_reference(const torch::Tensor& grad, const std::vector<torch::Tensor>& slots,
                                       const torch::Tensor& parameter, double decay) {
  // In finish()'s order: the gradient before, the slots in order, then the decay's term.
  auto out = grad.defined() ? grad.clone() : torch::zeros_like(parameter);
  for (const auto& s : slots) out = out + s;
  return out + parameter * (2 * decay);
}

}  // namespace ablenerf
