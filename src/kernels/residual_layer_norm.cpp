#include "kernels/residual_layer_norm.h"

#include "kernels/tensor_checks.h"

#ifdef ABLENERF_CUDA_KERNELS
#include <ATen/cuda/CUDAContext.h>
#include <c10/cuda/CUDAGuard.h>

#include "kernels/aten_cuda.h"
#include "kernels/residual_layer_norm_launch.h"
#endif

namespace ablenerf {

torch::Tensor residual_layer_norm_reference(const torch::Tensor& x, const torch::Tensor& r, const torch::Tensor& gamma,
                                            const torch::Tensor& beta, double eps) {
  TORCH_CHECK(x.dim() >= 1 && x.sizes() == r.sizes(), "residual_layer_norm_reference: x ", x.sizes(), " and r ",
              r.sizes(), " must have one shape");
  const auto compute = at::promote_types(x.scalar_type(), torch::kFloat);
  const auto s = x.to(compute) + r.to(compute);
  return at::layer_norm(s, {x.size(-1)}, gamma.to(compute), beta.to(compute), eps).to(x.scalar_type());
}

#ifdef ABLENERF_CUDA_KERNELS

namespace {

constexpr const char* kResidualLayerNormOp = "residual_layer_norm";

void check_inputs(const torch::Tensor& x, const torch::Tensor& r, const torch::Tensor& gamma, const torch::Tensor& beta,
                  double eps) {
  namespace check = kernel_checks;
  check::cuda(kResidualLayerNormOp, "x", x);
  check::activation_dtype(kResidualLayerNormOp, "x", x);
  check::contiguous(kResidualLayerNormOp, "x", x);
  TORCH_CHECK(x.dim() >= 1, kResidualLayerNormOp, ": x must have at least one dimension");
  const int64_t width = x.size(-1);
  TORCH_CHECK(residual_layer_norm_width_supported(width), kResidualLayerNormOp, ": x's last dimension (", width,
              ") must be a multiple of 32 in [32, ", kResidualLayerNormMaxWidth, "]");
  check::cuda(kResidualLayerNormOp, "r", r);
  check::same_device(kResidualLayerNormOp, "r", r, x);
  TORCH_CHECK(r.sizes() == x.sizes(), kResidualLayerNormOp, ": r must have x's shape ", x.sizes(), ", got ", r.sizes());
  check::dtype(kResidualLayerNormOp, "r", r, x.scalar_type());
  check::contiguous(kResidualLayerNormOp, "r", r);
  check::parameter_vector(kResidualLayerNormOp, "gamma", gamma, width, x);
  check::parameter_vector(kResidualLayerNormOp, "beta", beta, width, x);
  TORCH_CHECK(eps >= 0, kResidualLayerNormOp, ": eps must be >= 0, got ", eps);
}

// Saved for backward: x and r themselves (no extra memory: autograd keeps references; backward
// recomputes the float sum exactly) and the row statistics [mean; rstd] (2, rows).
class ResidualLayerNormFunction : public torch::autograd::Function<ResidualLayerNormFunction> {
 public:
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& x, const torch::Tensor& r,
                               const torch::Tensor& gamma, const torch::Tensor& beta, double eps) {
    const c10::cuda::CUDAGuard device(x.device());
    const int width = int(x.size(-1));
    const int64_t rows = x.numel() / width;
    auto y = torch::empty(x.sizes(), x.options());
    auto stats = torch::empty({2, rows}, x.options().dtype(torch::kFloat));
    aten_cuda::dispatch_activation(x, [&](auto tag) {
      C10_CUDA_CHECK(launch_residual_layer_norm_forward(
          aten_cuda::ptr(x, tag), aten_cuda::ptr(r, tag), gamma.data_ptr<float>(), beta.data_ptr<float>(), rows, width,
          float(eps), aten_cuda::mutable_ptr(y, tag), stats.data_ptr<float>(), stats.data_ptr<float>() + rows,
          at::cuda::getCurrentCUDAStream()));
    });
    ctx->save_for_backward({x, r, gamma, stats});
    return y;
  }

  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                 torch::autograd::variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    const auto &x = saved[0], &r = saved[1], &gamma = saved[2], &stats = saved[3];
    const c10::cuda::CUDAGuard device(x.device());
    const int width = int(x.size(-1));
    const int64_t rows = x.numel() / width;
    const auto dy = grads[0].to(x.scalar_type()).contiguous();
    auto ds = torch::empty(x.sizes(), x.options());
    auto dgb = torch::empty({2, width}, gamma.options());
    auto workspace = torch::empty({int64_t(residual_layer_norm_backward_workspace(rows, width))}, gamma.options());
    aten_cuda::dispatch_activation(x, [&](auto tag) {
      C10_CUDA_CHECK(launch_residual_layer_norm_backward(
          aten_cuda::ptr(dy, tag), aten_cuda::ptr(x, tag), aten_cuda::ptr(r, tag), gamma.data_ptr<float>(),
          stats.data_ptr<float>(), stats.data_ptr<float>() + rows, rows, width, aten_cuda::mutable_ptr(ds, tag),
          dgb.data_ptr<float>(), workspace.data_ptr<float>(), at::cuda::getCurrentCUDAStream()));
    });
    return {ds, ds, dgb[0], dgb[1], torch::Tensor()};
  }
};

}  // namespace

torch::Tensor residual_layer_norm(const torch::Tensor& x, const torch::Tensor& r, const torch::Tensor& gamma,
                                  const torch::Tensor& beta, double eps) {
  check_inputs(x, r, gamma, beta, eps);
  return ResidualLayerNormFunction::apply(x, r, gamma, beta, eps);
}

#else

torch::Tensor residual_layer_norm(const torch::Tensor&, const torch::Tensor&, const torch::Tensor&,
                                  const torch::Tensor&, double) {
  TORCH_CHECK(false, "residual_layer_norm: built without CUDA kernels (configure against a CUDA LibTorch)");
}

#endif

}  // namespace ablenerf
