#include "train/adam.h"

#include <torch/version.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>
#include <type_traits>

#include "kernels/adam_cpu.h"
#include "kernels/cpu_parallel.h"

namespace ablenerf {

namespace {
constexpr double kWeightDecay = 0.0;
constexpr int64_t kElementsPerTask = 1 << 16;

// Whether x[0, n) are all finite: x * 0 is 0 for a finite x and NaN for an infinite or NaN one, so
// branch-free sums in 8 independent lanes (kept in vector registers by the compiler) say it.
bool elements_finite(const float* x, int64_t n) {
  constexpr int64_t kLanes = 8;
  float probe[kLanes] = {};
  int64_t i = 0;
  for (; i + kLanes <= n; i += kLanes)
    for (int64_t k = 0; k < kLanes; ++k) probe[k] += x[i + k] * 0.0f;
  for (; i < n; ++i) probe[0] += x[i] * 0.0f;
  for (const float lane : probe)
    if (lane != 0.0f) return false;
  return true;
}
#if defined(ABLENERF_WITH_CUDA) && TORCH_VERSION_MAJOR >= 2
constexpr bool kDeviceFormCompiled = true;
#else
constexpr bool kDeviceFormCompiled = false;
#endif
// The key torch::optim keeps a parameter's state under (a string in LibTorch 1.x, a pointer in 2.x).
template <class Map>
typename Map::key_type state_key(const Map&, const torch::Tensor& p) {
  if constexpr (std::is_same_v<typename Map::key_type, std::string>) {
    std::ostringstream os;  // what LibTorch 1.x writes: the TensorImpl's address
    os << p.unsafeGetTensorImpl();
    return os.str();
  } else {
    return static_cast<typename Map::key_type>(p.unsafeGetTensorImpl());
  }
}

template <class Map>
torch::optim::AdamParamState& adam_state(Map& state, const torch::Tensor& p) {
  return static_cast<torch::optim::AdamParamState&>(*state.at(state_key(state, p)));
}

// The state torch::optim::Adam creates on a parameter's first step: step 0, zero moments.
template <class Map>
void add_zero_state(Map& state, const torch::Tensor& p) {
  auto st = std::make_unique<torch::optim::AdamParamState>();
  st->step(0);
  st->exp_avg(torch::zeros_like(p, torch::MemoryFormat::Preserve));
  st->exp_avg_sq(torch::zeros_like(p, torch::MemoryFormat::Preserve));
  state[state_key(state, p)] = std::move(st);
}

}  // namespace

torch::optim::AdamParamState& Adam::state_of(const torch::Tensor& p) { return adam_state(optim_.state(), p); }

bool Adam::device_form_available(const torch::Device& device) { return kDeviceFormCompiled && device.is_cuda(); }

Adam::Adam(std::vector<torch::Tensor> params, double lr, bool device_form, const AdamSettings& settings)
    : params_(std::move(params)),
      settings_(settings),
      optim_(params_, torch::optim::AdamOptions(lr)
                          .betas({settings.beta1, settings.beta2})
                          .eps(settings.eps)
                          .weight_decay(kWeightDecay)),
      device_form_(device_form) {
  if (!device_form_) {
    host_loops_ = !params_.empty() && std::all_of(params_.begin(), params_.end(), [](const torch::Tensor& p) {
      return p.device().is_cpu() && p.scalar_type() == torch::kFloat && p.is_contiguous();
    });
    return;
  }
  if (params_.empty() || !device_form_available(params_.front().device()))
    throw std::invalid_argument("the device form of Adam needs CUDA parameters and a CUDA LibTorch >= 2");
  const auto dev = params_.front().device();
  const auto f32 = torch::TensorOptions().dtype(torch::kFloat).device(dev);
  step_ = torch::zeros({}, f32);
  lr_ = torch::full({}, lr, f32);
  found_inf_ = torch::zeros({1}, f32);
  // The per-parameter state torch::optim::Adam would create on its first step, created now so
  // that the kernel and checkpoints share the same tensors.
  for (auto& p : params_) add_zero_state(optim_.state(), p);
  bind_state();
}

void Adam::bind_state() {
  exp_avg_.clear();
  exp_avg_sq_.clear();
  int64_t step = 0;
  for (auto& p : params_) {
    auto& st = adam_state(optim_.state(), p);
    exp_avg_.push_back(st.exp_avg());
    exp_avg_sq_.push_back(st.exp_avg_sq());
    step = st.step();
  }
  torch::NoGradGuard no_grad;
  step_.fill_(static_cast<double>(step));
}

void Adam::set_lr(double lr) {
  if (device_form_) {
    lr_.fill_(lr);
    return;
  }
  for (auto& g : optim_.param_groups()) static_cast<torch::optim::AdamOptions&>(g.options()).lr(lr);
}

void Adam::clear_grads() {
  for (auto& p : params_) p.mutable_grad() = torch::Tensor();
}

bool Adam::step_host(double loss, const std::vector<torch::Tensor>& checked, std::vector<TableStep>* tables) {
  // A skipped step's tables drop their lookups as a cleared gradient would.
  const auto skip = [&] {
    if (tables != nullptr)
      for (auto& t : *tables) t.gradient->discard();
    return false;
  };
  TORCH_CHECK(tables == nullptr || tables->empty() || host_loops_,
              "Adam: tables whose gradient is formed in the update need the host loops");
  if (!std::isfinite(loss)) return skip();
  if (host_loops_) {
    const auto was_checked = [&](const torch::Tensor& p) {
      return std::any_of(checked.begin(), checked.end(), [&](const torch::Tensor& c) { return c.is_same(p); });
    };
    // Each gradient made contiguous once (most already are), for both loops; the finite check
    // over the ones not checked already.
    std::vector<torch::Tensor> grads, unchecked;
    for (const auto& p : params_) {
      grads.push_back(p.grad().defined() ? p.grad().contiguous() : torch::Tensor());
      if (!was_checked(p)) unchecked.push_back(grads.back());
    }
    if (!gradients_finite_loop(unchecked)) return skip();
    if (tables != nullptr)
      for (const auto& t : *tables)
        if (!t.gradient->lookups_finite()) return skip();
    update_loop(grads);
    return tables == nullptr || update_tables(*tables);
  }
  std::vector<torch::Tensor> norms;
  for (const auto& p : params_)
    if (p.grad().defined()) norms.push_back(p.grad().abs().max());
  if (!norms.empty() && !torch::stack(norms).isfinite().all().item<bool>()) return false;
  optim_.step();
  return true;
}

bool Adam::gradients_finite_loop(const std::vector<torch::Tensor>& grads) {
  // The gradients as one run of elements, split between the threads (the grid's tables are a
  // million entries or more; read by one thread the check took a sixth of the step's Adam).
  std::vector<const float*> data;
  std::vector<int64_t> ends;  // running element count
  int64_t total = 0;
  for (const auto& g : grads) {
    if (!g.defined() || g.numel() == 0) continue;
    data.push_back(g.data_ptr<float>());
    total += g.numel();
    ends.push_back(total);
  }
  std::atomic<bool> finite{true};
  parallel_slices(total, cpu_workers(total, kElementsPerTask), [&](int64_t, int64_t lo, int64_t hi) {
    size_t k = static_cast<size_t>(std::upper_bound(ends.begin(), ends.end(), lo) - ends.begin());
    for (int64_t at = lo; at < hi && finite.load(std::memory_order_relaxed); ++k) {
      const int64_t start = k == 0 ? 0 : ends[k - 1];
      const int64_t stop = std::min(ends[k], hi);
      if (!elements_finite(data[k] + (at - start), stop - at)) finite.store(false, std::memory_order_relaxed);
      at = stop;
    }
  });
  return finite.load();
}

// torch::optim::Adam::step (LibTorch 1.13, no weight decay, no amsgrad) element by element
// (kernels/adam_cpu.h): the same per-parameter state (created on a parameter's first gradient, step
// counted per parameter) and the same operations in the same order, in float32.
torch::optim::AdamParamState& Adam::advance(const torch::Tensor& p, AdamScalars& scalars) {
  auto& state = optim_.state();
  const auto key = state_key(state, p);
  if (state.count(key) == 0) add_zero_state(state, p);
  auto& st = static_cast<torch::optim::AdamParamState&>(*state.at(key));
  st.step(st.step() + 1);
  const double lr = static_cast<torch::optim::AdamOptions&>(optim_.param_groups().front().options()).lr();
  // The scalars as the tensor ops see them: cast to float once.
  const double beta1 = settings_.beta1, beta2 = settings_.beta2;
  const double bias1 = 1.0 - std::pow(beta1, static_cast<double>(st.step()));
  const double bias2 = 1.0 - std::pow(beta2, static_cast<double>(st.step()));
  scalars = {static_cast<float>(beta1),        static_cast<float>(1.0 - beta1),   static_cast<float>(beta2),
             static_cast<float>(1.0 - beta2),  static_cast<float>(settings_.eps), static_cast<float>(std::sqrt(bias2)),
             static_cast<float>(-(lr / bias1))};
  TORCH_CHECK(st.exp_avg().is_contiguous() && st.exp_avg_sq().is_contiguous() &&
                  st.exp_avg().scalar_type() == torch::kFloat && st.exp_avg_sq().scalar_type() == torch::kFloat &&
                  st.exp_avg().numel() == p.numel() && st.exp_avg_sq().numel() == p.numel(),
              "Adam: the moments of a ", p.sizes(), " parameter are not contiguous float32 tensors of its size");
  return st;
}

bool Adam::update_tables(std::vector<TableStep>& tables) {
  torch::NoGradGuard no_grad;
  bool finite = true;
  for (auto& t : tables) {
    t.value = 0.0;
    if (!t.gradient->pending() && t.decay == 0) continue;  // no gradient: no step, as for .grad
    AdamScalars scalars{};
    auto& st = advance(t.param, scalars);
    t.value = t.gradient->finish_adam(t.param, t.decay, scalars, st.exp_avg().data_ptr<float>(),
                                      st.exp_avg_sq().data_ptr<float>());
    finite = finite && t.gradient->wrote_finite_gradient();
  }
  return finite;
}

void Adam::update_loop(const std::vector<torch::Tensor>& grads) {
  torch::NoGradGuard no_grad;
  for (size_t i = 0; i < params_.size(); ++i) {
    auto& p = params_[i];
    const auto& gc = grads[i];
    if (!gc.defined()) continue;
    AdamScalars scalars{};
    auto& st = advance(p, scalars);
    TORCH_CHECK(gc.scalar_type() == torch::kFloat && gc.numel() == p.numel(), "Adam: the gradient of a ", p.sizes(),
                " parameter is ", gc.scalar_type(), " ", gc.sizes());
    const float* g = gc.data_ptr<float>();
    float* m = st.exp_avg().data_ptr<float>();
    float* v = st.exp_avg_sq().data_ptr<float>();
    float* w = p.data_ptr<float>();
    // Element by element, so splitting the range over threads changes no bit (the grid's table is
    // a million entries; the transformer's matrices are far smaller and stay on one thread). The
    // project's own threads (kernels/cpu_parallel.h), not at::parallel_for: that one is serial in
    // code built without OpenMP, as ours is.
    const auto part = entries_.find(p.unsafeGetTensorImpl());
    const IndexRanges all{{0, p.numel()}};
    const IndexRanges& ranges = part != entries_.end() && !part->second.empty() ? part->second : all;
    TORCH_CHECK(ranges.back().second <= p.numel(), "Adam: entries up to ", ranges.back().second, " of a ", p.sizes(),
                " parameter");
    parallel_ranges(ranges, cpu_workers(index_count(ranges), kElementsPerTask), [&](int64_t, int64_t lo, int64_t hi) {
      adam_update_cpu(hi - lo, g + lo, m + lo, v + lo, w + lo, scalars);
    });
  }
}

void Adam::set_entries(const torch::Tensor& param, IndexRanges entries) {
  entries_[param.unsafeGetTensorImpl()] = std::move(entries);
}

void Adam::step_device(const torch::Tensor& loss) {
#if defined(ABLENERF_WITH_CUDA) && TORCH_VERSION_MAJOR >= 2
  torch::NoGradGuard no_grad;
  std::vector<torch::Tensor> params, grads, exp_avg, exp_avg_sq;
  for (size_t i = 0; i < params_.size(); ++i) {
    if (!params_[i].grad().defined()) continue;  // an unused parameter keeps its state
    params.push_back(params_[i]);
    grads.push_back(params_[i].grad());
    exp_avg.push_back(exp_avg_[i]);
    exp_avg_sq.push_back(exp_avg_sq_[i]);
  }
  // found_inf = 1 when the loss or any gradient is not finite (inv_scale 1 leaves them as they are).
  found_inf_.copy_((~torch::isfinite(loss.detach().to(torch::kFloat))).to(torch::kFloat).reshape({1}));
  at::_amp_foreach_non_finite_check_and_unscale_(grads, found_inf_, torch::ones({}, found_inf_.options()));
  // The kernel reads the step count after it is advanced, and does not advance it itself; a
  // skipped step leaves it where it was.
  step_.add_(1.0 - found_inf_.squeeze(0));
  const std::vector<torch::Tensor> steps(params.size(), step_);
  at::_fused_adam_(params, grads, exp_avg, exp_avg_sq, /*max_exp_avg_sqs=*/{}, steps, lr_, settings_.beta1,
                   settings_.beta2, kWeightDecay, settings_.eps, /*amsgrad=*/false, /*maximize=*/false,
                   /*grad_scale=*/std::nullopt, found_inf_);
#else
  (void)loss;
  throw std::logic_error("Adam::step_device: not compiled in (needs a CUDA LibTorch >= 2)");
#endif
}

void Adam::to_checkpoint() {
  if (!device_form_) return;
  const auto step = static_cast<int64_t>(std::llround(step_.item<double>()));
  for (auto& p : params_) adam_state(optim_.state(), p).step(step);
}

void Adam::from_checkpoint() {
  for (auto& g : optim_.param_groups())
    static_cast<torch::optim::AdamOptions&>(g.options()).betas({settings_.beta1, settings_.beta2}).eps(settings_.eps);
  if (device_form_) bind_state();
}

}  // namespace ablenerf
