#include "kernels/bias_gelu.h"

#include <limits>

#include "kernels/tensor_checks.h"

#ifdef ABLENERF_CUDA_KERNELS
#include <ATen/cuda/CUDAContext.h>
#include <c10/cuda/CUDAGuard.h>

#include "kernels/aten_cuda.h"
#include "kernels/bias_gelu_launch.h"
#endif

namespace ablenerf {

torch::Tensor bias_gelu_reference(const torch::Tensor& x, const torch::Tensor& b) {
  TORCH_CHECK(x.dim() >= 1 && b.dim() == 1 && b.size(0) == x.size(-1), "bias_gelu_reference: b ", b.sizes(),
              " must have x's last dimension, x ", x.sizes());
  const auto compute = at::promote_types(x.scalar_type(), torch::kFloat);
  return torch::gelu(x.to(compute) + b.to(compute)).to(x.scalar_type());
}

#ifdef ABLENERF_CUDA_KERNELS

namespace {

constexpr const char* kBiasGeluOp = "bias_gelu";

void check_inputs(const torch::Tensor& x, const torch::Tensor& b) {
  namespace check = kernel_checks;
  check::cuda(kBiasGeluOp, "x", x);
  check::activation_dtype(kBiasGeluOp, "x", x);
  check::contiguous(kBiasGeluOp, "x", x);
  TORCH_CHECK(x.dim() >= 1, kBiasGeluOp, ": x must have at least one dimension");
  TORCH_CHECK(x.size(-1) <= std::numeric_limits<int>::max(), kBiasGeluOp, ": x's last dimension is too large");
  check::parameter_vector(kBiasGeluOp, "b", b, x.size(-1), x);
}

// Saved for backward: x and b (x + b is recomputed; no pre-activation is stored).
class BiasGeluFunction : public torch::autograd::Function<BiasGeluFunction> {
 public:
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& x, const torch::Tensor& b) {
    const c10::cuda::CUDAGuard device(x.device());
    const int cols = int(x.size(-1));
    const int64_t rows = cols == 0 ? 0 : x.numel() / cols;
    auto y = torch::empty(x.sizes(), x.options());
    aten_cuda::dispatch_activation(x, [&](auto tag) {
      C10_CUDA_CHECK(launch_bias_gelu_forward(aten_cuda::ptr(x, tag), b.data_ptr<float>(), rows, cols,
                                              aten_cuda::mutable_ptr(y, tag), at::cuda::getCurrentCUDAStream()));
    });
    ctx->save_for_backward({x, b});
    return y;
  }

  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                 torch::autograd::variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    const auto &x = saved[0], &b = saved[1];
    const c10::cuda::CUDAGuard device(x.device());
    const int cols = int(x.size(-1));
    const int64_t rows = cols == 0 ? 0 : x.numel() / cols;
    const auto dy = grads[0].to(x.scalar_type()).contiguous();
    auto dx = torch::empty(x.sizes(), x.options());
    auto db = torch::empty({cols}, b.options());
    auto workspace = torch::empty({int64_t(bias_gelu_backward_workspace(rows, cols))}, b.options());
    aten_cuda::dispatch_activation(x, [&](auto tag) {
      C10_CUDA_CHECK(launch_bias_gelu_backward(aten_cuda::ptr(dy, tag), aten_cuda::ptr(x, tag), b.data_ptr<float>(),
                                               rows, cols, aten_cuda::mutable_ptr(dx, tag), db.data_ptr<float>(),
                                               workspace.data_ptr<float>(), at::cuda::getCurrentCUDAStream()));
    });
    return {dx, db};
  }
};

}  // namespace

torch::Tensor bias_gelu(const torch::Tensor& x, const torch::Tensor& b) {
  check_inputs(x, b);
  return BiasGeluFunction::apply(x, b);
}

#else

torch::Tensor bias_gelu(const torch::Tensor&, const torch::Tensor&) {
  TORCH_CHECK(false, "bias_gelu: built without CUDA kernels (configure against a CUDA LibTorch)");
}

#endif

}  // namespace ablenerf
