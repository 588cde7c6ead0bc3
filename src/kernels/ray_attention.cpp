#include "kernels/ray_attention.h"

#include <cmath>
#include <cstdint>
#include <limits>

#ifdef ABLENERF_CUDA_KERNELS
#include <ATen/cuda/CUDAContext.h>
#include <c10/cuda/CUDAException.h>
#include <c10/cuda/CUDAGuard.h>

#include "kernels/aten_cuda.h"
#include "kernels/ray_attention_launch.h"
#endif
#include "kernels/tensor_checks.h"

namespace ablenerf {

namespace {

// B, L, H and the head width of a packed (B, L, 3E) tensor, checked for consistency.
struct Geometry {
  int64_t batch, tokens, heads, width, head_dim;
};

Geometry geometry(const torch::Tensor& qkv, int64_t heads, const char* fn) {
  TORCH_CHECK(qkv.defined(), fn, ": qkv is undefined");
  TORCH_CHECK(qkv.dim() == 3, fn, ": qkv must be (B, L, 3E), got sizes ", qkv.sizes());
  TORCH_CHECK(heads >= 1, fn, ": heads must be >= 1, got ", heads);
  TORCH_CHECK(qkv.size(2) % (3 * heads) == 0, fn, ": qkv.size(2) = ", qkv.size(2), " is not 3 * heads * head_dim for ",
              heads, " heads");
  TORCH_CHECK(qkv.size(1) >= 1, fn, ": qkv.size(1) (tokens) must be >= 1");
  const int64_t width = qkv.size(2) / 3;
  return {qkv.size(0), qkv.size(1), heads, width, width / heads};
}

#ifdef ABLENERF_CUDA_KERNELS

// The kernels load bf16 rows 16 bytes at a time; fresh allocations always qualify, views may not.
torch::Tensor aligned(const torch::Tensor& x) {
  return reinterpret_cast<std::uintptr_t>(x.data_ptr()) % 16 == 0 ? x : x.clone();
}

kernels::RayAttentionShape kernel_shape(const Geometry& g, bool masked) {
  kernels::RayAttentionShape s;
  s.batch = g.batch;
  s.tokens = int(g.tokens);
  s.heads = int(g.heads);
  s.masked = masked;
  return s;
}

// out, row0 and the per-row log-sum-exp of a checked, contiguous, aligned qkv.
struct Forward {
  torch::Tensor out, row0, lse;
};

Forward run_forward(const torch::Tensor& qkv, const Geometry& g, bool masked) {
  const c10::cuda::CUDAGuard guard(qkv.device());
  Forward f;
  f.out = torch::empty({g.batch, g.tokens, g.width}, qkv.options());
  const auto fp32 = qkv.options().dtype(torch::kFloat);
  f.row0 = torch::empty({g.batch, g.heads, g.tokens}, fp32);
  f.lse = torch::empty({g.batch, g.heads, g.tokens}, fp32);
  const auto shape = kernel_shape(g, masked);
  const cudaStream_t stream = at::cuda::getCurrentCUDAStream();
  cudaError_t err = cudaSuccess;
  aten_cuda::dispatch_activation(qkv, [&](auto tag) {
    err = kernels::launch_ray_attention_forward(aten_cuda::ptr(qkv, tag), aten_cuda::mutable_ptr(f.out, tag),
                                                f.lse.data_ptr<float>(), f.row0.data_ptr<float>(), shape, stream);
  });
  C10_CUDA_CHECK(err);
  C10_CUDA_KERNEL_LAUNCH_CHECK();
  return f;
}

torch::Tensor run_backward(const torch::Tensor& qkv, const torch::Tensor& out, const torch::Tensor& lse,
                           const torch::Tensor& grad_out, int64_t heads, bool masked) {
  const Geometry g = geometry(qkv, heads, "ray_attention backward");
  const c10::cuda::CUDAGuard guard(qkv.device());
  const auto go = aligned(grad_out.to(out.scalar_type()).contiguous());
  TORCH_CHECK(go.sizes() == out.sizes(), "ray_attention backward: grad_out has sizes ", go.sizes(), ", expected ",
              out.sizes());
  auto grad = torch::empty(qkv.sizes(), qkv.options());
  const auto shape = kernel_shape(g, masked);
  const cudaStream_t stream = at::cuda::getCurrentCUDAStream();
  cudaError_t err = cudaSuccess;
  aten_cuda::dispatch_activation(qkv, [&](auto tag) {
    err = kernels::launch_ray_attention_backward(aten_cuda::ptr(qkv, tag), aten_cuda::ptr(out, tag),
                                                 aten_cuda::ptr(go, tag), lse.data_ptr<float>(),
                                                 aten_cuda::mutable_ptr(grad, tag), shape, stream);
  });
  C10_CUDA_CHECK(err);
  C10_CUDA_KERNEL_LAUNCH_CHECK();
  return grad;
}

// Autograd node: saves qkv, out and the log-sum-exp; the backward recomputes P from them.
class RayAttentionFunction : public torch::autograd::Function<RayAttentionFunction> {
 public:
  static torch::autograd::variable_list forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& qkv,
                                                int64_t heads, bool masked) {
    const Geometry g = geometry(qkv, heads, "ray_attention");
    Forward f = run_forward(qkv, g, masked);
    ctx->save_for_backward({qkv, f.out, f.lse});
    ctx->saved_data["heads"] = heads;
    ctx->saved_data["masked"] = masked;
    ctx->mark_non_differentiable({f.row0});
    return {f.out, f.row0};
  }

  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                 torch::autograd::variable_list grads) {
    if (!grads[0].defined()) return {torch::Tensor(), torch::Tensor(), torch::Tensor()};
    const auto saved = ctx->get_saved_variables();
    const auto grad = run_backward(saved[0], saved[1], saved[2], grads[0], ctx->saved_data["heads"].toInt(),
                                   ctx->saved_data["masked"].toBool());
    return {grad, torch::Tensor(), torch::Tensor()};
  }
};

#endif  // ABLENERF_CUDA_KERNELS

}  // namespace

RayAttentionResult ray_attention(const torch::Tensor& qkv, int64_t heads, bool masked) {
#ifdef ABLENERF_CUDA_KERNELS
  const Geometry g = geometry(qkv, heads, "ray_attention");
  kernel_checks::cuda("ray_attention", "qkv", qkv);
  kernel_checks::activation_dtype("ray_attention", "qkv", qkv);
  TORCH_CHECK(g.head_dim == kernels::kRayAttentionHeadDim,
              "ray_attention: head_dim (qkv.size(2) / (3 * heads)) must be ", kernels::kRayAttentionHeadDim, ", got ",
              g.head_dim);
  TORCH_CHECK(g.tokens <= kernels::kRayAttentionMaxTokens, "ray_attention: qkv.size(1) (tokens) must be at most ",
              kernels::kRayAttentionMaxTokens, ", got ", g.tokens);
  TORCH_CHECK(g.batch * heads <= std::numeric_limits<int32_t>::max(),
              "ray_attention: qkv.size(0) * heads = ", g.batch * heads, " exceeds the kernels' grid");
  const auto x = aligned(qkv.contiguous());
  const auto r = RayAttentionFunction::apply(x, heads, masked);
  return {r[0], r[1]};
#else
  (void)qkv;
  (void)heads;
  (void)masked;
  TORCH_CHECK(false, "ray_attention: built without CUDA kernels (ABLENERF_CUDA_KERNELS); use ray_attention_reference");
#endif
}

RayAttentionResult ray_attention_reference(const torch::Tensor& qkv, int64_t heads, bool masked) {
  const Geometry g = geometry(qkv, heads, "ray_attention_reference");
  TORCH_CHECK(at::isFloatingType(qkv.scalar_type()), "ray_attention_reference: qkv must be floating point, got ",
              qkv.scalar_type());
  // fp32 accumulation for fp32 / bf16 / fp16, float64 stays float64.
  const auto compute = qkv.scalar_type() == torch::kDouble ? torch::kDouble : torch::kFloat;
  const auto x = qkv.to(compute);
  const auto head_view = [&](int64_t part) {  // (B, H, L, dh)
    return x.narrow(2, part * g.width, g.width).reshape({g.batch, g.tokens, g.heads, g.head_dim}).transpose(1, 2);
  };
  const auto q = head_view(0), k = head_view(1), v = head_view(2);
  auto scores = torch::matmul(q, k.transpose(-2, -1)) * (1.0 / std::sqrt(double(g.head_dim)));
  if (masked) {
    // Strict upper triangle blocked (key after query), except row 0, the ray token.
    auto blocked = torch::ones({g.tokens, g.tokens}, x.options().dtype(torch::kBool)).triu(1);
    blocked.select(0, 0).fill_(false);
    scores = scores.masked_fill(blocked, -std::numeric_limits<double>::infinity());
  }
  const auto p = torch::softmax(scores, -1);
  auto out = torch::matmul(p, v).transpose(1, 2).reshape({g.batch, g.tokens, g.width}).to(qkv.scalar_type());
  auto row0 = p.select(2, 0).detach().contiguous();  // (B, H, L), already float32 or float64
  return {out, row0};
}

bool ray_attention_supports(int64_t tokens, int64_t head_width) {
#ifdef ABLENERF_CUDA_KERNELS
  return head_width == kernels::kRayAttentionHeadDim && tokens >= 1 && tokens <= kernels::kRayAttentionMaxTokens;
#else
  (void)tokens;
  (void)head_width;
  return false;
#endif
}

}  // namespace ablenerf
