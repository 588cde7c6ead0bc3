#include "model/attention_core.h"

#include <dlfcn.h>

#include <algorithm>
#include <thread>
#include <vector>

namespace ablenerf {

namespace {

// Below this many matrices per thread the thread start-up costs more than it saves.
constexpr int64_t kMinMatricesPerThread = 16;

// OpenBLAS's runtime thread control, looked up at run time so that other BLAS builds (or a
// LibTorch with MKL) simply skip it.
using SetThreads = void (*)(int);
using GetThreads = int (*)();

struct BlasThreads {
  SetThreads set = nullptr;
  GetThreads get = nullptr;
  BlasThreads() {
    set = reinterpret_cast<SetThreads>(dlsym(RTLD_DEFAULT, "openblas_set_num_threads"));
    get = reinterpret_cast<GetThreads>(dlsym(RTLD_DEFAULT, "openblas_get_num_threads"));
    if (!set || !get) set = nullptr, get = nullptr;
  }
};

const BlasThreads& blas_threads() {
  static const BlasThreads b;
  return b;
}

// Single-threaded BLAS for the scope (restores the previous count).
class SingleThreadedBlas {
 public:
  SingleThreadedBlas() {
    const auto& b = blas_threads();
    if (b.set) {
      previous_ = b.get();
      if (previous_ != 1) b.set(1);
    }
  }
  ~SingleThreadedBlas() {
    const auto& b = blas_threads();
    if (b.set && previous_ > 1) b.set(previous_);
  }
  SingleThreadedBlas(const SingleThreadedBlas&) = delete;
  SingleThreadedBlas& operator=(const SingleThreadedBlas&) = delete;

 private:
  int previous_ = 0;
};

int64_t worker_count(int64_t n) {
  // The threads the user allows: LibTorch's intra-op pool or OpenBLAS's (which follows
  // OPENBLAS_NUM_THREADS / OMP_NUM_THREADS), whichever is larger; LibTorch 1.13 here defaults to
  // one intra-op thread while OpenBLAS uses every core.
  const auto& blas = blas_threads();
  const int64_t cores = std::max<int64_t>({1, at::get_num_threads(), blas.get ? blas.get() : 1});
  return std::max<int64_t>(1, std::min(cores, n / kMinMatricesPerThread));
}

// out[i] = a[i] @ b[i] for the whole batch, split into contiguous slices, one per thread.
void bmm_into(torch::Tensor& out, const torch::Tensor& a, const torch::Tensor& b) {
  const int64_t n = a.size(0), workers = worker_count(n);
  if (!a.device().is_cpu() || workers == 1 || !blas_threads().set) {
    at::bmm_out(out, a, b);
    return;
  }
  SingleThreadedBlas single;
  const bool inference = c10::InferenceMode::is_enabled();
  const auto slice = [&](int64_t w) {
    const int64_t lo = n * w / workers, hi = n * (w + 1) / workers;
    auto o = out.slice(0, lo, hi);
    at::bmm_out(o, a.slice(0, lo, hi), b.slice(0, lo, hi));
  };
  std::vector<std::thread> threads;
  for (int64_t w = 1; w < workers; ++w)
    threads.emplace_back([&, w] {
      // Grad and inference modes are thread-local: mirror the caller's (no graph is recorded
      // here; autograd is handled by AttentionCoreFunction).
      c10::InferenceMode inference_guard(inference);
      torch::NoGradGuard no_grad;
      slice(w);
    });
  {
    torch::NoGradGuard no_grad;
    slice(0);
  }
  for (auto& t : threads) t.join();
}

torch::Tensor forward_probabilities(const torch::Tensor& q, const torch::Tensor& k, const torch::Tensor& mask,
                                    double scale) {
  auto scores = batched_matmul(q, k.transpose(1, 2));
  scores.mul_(scale);
  if (mask.defined() && mask.numel() > 0) scores.add_(mask);
  return torch::softmax(scores, -1);
}

class AttentionCoreFunction : public torch::autograd::Function<AttentionCoreFunction> {
 public:
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& q, const torch::Tensor& k,
                               const torch::Tensor& v, const torch::Tensor& mask, double scale) {
    const auto p = forward_probabilities(q, k, mask, scale);
    ctx->save_for_backward({q, k, v, p});
    ctx->saved_data["scale"] = scale;
    return batched_matmul(p, v);
  }

  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                 torch::autograd::variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    const auto &q = saved[0], &k = saved[1], &v = saved[2], &p = saved[3];
    const double scale = ctx->saved_data["scale"].toDouble();
    const auto go = grads[0].contiguous();
    const auto dv = batched_matmul(p.transpose(1, 2), go);
    const auto dp = batched_matmul(go, v.transpose(1, 2));
    // Softmax backward: dS = P * (dP - rowsum(dP * P)); the scale then multiplies dQ and dK.
    auto ds = dp - (dp * p).sum(-1, /*keepdim=*/true);
    ds.mul_(p);
    const auto dq = batched_matmul(ds, k).mul_(scale);
    const auto dk = batched_matmul(ds.transpose(1, 2), q).mul_(scale);
    return {dq, dk, dv, torch::Tensor(), torch::Tensor()};
  }
};

}  // namespace

torch::Tensor batched_matmul(const torch::Tensor& a, const torch::Tensor& b) {
  auto out = torch::empty({a.size(0), a.size(1), b.size(2)}, a.options());
  bmm_into(out, a, b);
  return out;
}

torch::Tensor attention_core(const torch::Tensor& q, const torch::Tensor& k, const torch::Tensor& v,
                             const torch::Tensor& mask, double scale) {
  const bool needs_graph =
      torch::GradMode::is_enabled() && (q.requires_grad() || k.requires_grad() || v.requires_grad());
  if (!needs_graph) return batched_matmul(forward_probabilities(q, k, mask, scale), v);
  // Autograd functions cannot take undefined tensors: "no mask" travels as an empty tensor.
  return AttentionCoreFunction::apply(q, k, v, mask.defined() ? mask : torch::empty({0}, q.options()), scale);
}

}  // namespace ablenerf
