#pragma once
// Fused residual add + LayerNorm: y = LayerNorm(x + r) * gamma + beta over the last dimension,
// the "x = LN(x + sublayer(x))" of a post-norm transformer block in one kernel (CUDA) with its
// own backward. The sum x + r and all statistics are float; the output has the inputs' dtype,
// so bfloat16 activations come out of LayerNorm already in bfloat16 (no casts around it).
#include <torch/torch.h>

namespace ablenerf {

// x, r: (..., E), CUDA, contiguous, both float32 or both bfloat16, E a multiple of 32 in
// [32, 1024]; gamma, beta: (E), float32, on x's device. Returns y shaped and typed as x.
// Differentiable in x, r, gamma and beta (x and r receive the same gradient). Throws c10::Error
// naming the argument on bad input, and "built without CUDA kernels" where they were not built.
torch::Tensor residual_layer_norm(const torch::Tensor& x, const torch::Tensor& r, const torch::Tensor& gamma,
                                  const torch::Tensor& beta, double eps);

// The plain LibTorch version the kernel is tested against, on any device and for any floating
// dtype: at::layer_norm(x + r) computed in float32 (float64 stays float64), returned in x's dtype.
torch::Tensor residual_layer_norm_reference(const torch::Tensor& x, const torch::Tensor& r, const torch::Tensor& gamma,
                                            const torch::Tensor& beta, double eps);

}  // namespace ablenerf
