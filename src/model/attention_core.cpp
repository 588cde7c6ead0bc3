#include "model/attention_core.h"

#include "model/cpu_parallel.h"

namespace ablenerf {

namespace {

// Below this many matrices per thread the thread start-up costs more than it saves.
constexpr int64_t kMinMatricesPerThread = 16;

// out[i] = a[i] @ b[i] for the whole batch, split into contiguous slices, one per thread. Grad
// recording is off in the workers: autograd is handled by AttentionCoreFunction.
void bmm_into(torch::Tensor& out, const torch::Tensor& a, const torch::Tensor& b) {
  const int64_t n = a.size(0);
  const int64_t workers = a.device().is_cpu() ? cpu_workers(n, kMinMatricesPerThread) : 1;
  torch::NoGradGuard no_grad;
  parallel_slices(n, workers, [&](int64_t, int64_t lo, int64_t hi) {
    auto o = out.slice(0, lo, hi);
    at::bmm_out(o, a.slice(0, lo, hi), b.slice(0, lo, hi));
  });
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
