#pragma once
// Fused bias + exact GELU: y = gelu(x + b), gelu(z) = z * Phi(z) with the erf-based normal CDF
// (not the tanh approximation, which cuBLASLt's GELU epilogue uses), in one kernel (CUDA) with
// its own backward; the bias gradient comes out of the same pass.
#include <torch/torch.h>

namespace ablenerf {

// x: (..., F), CUDA, contiguous, float32 or bfloat16; b: (F), float32, on x's device. Returns y
// shaped and typed as x, computed in float. Differentiable in x and b. Throws c10::Error naming
// the argument on bad input, and "built without CUDA kernels" where they were not built.
torch::Tensor bias_gelu(const torch::Tensor& x, const torch::Tensor& b);

// The plain LibTorch version the kernel is tested against, on any device and for any floating
// dtype: torch::gelu(x + b) computed in float32 (float64 stays float64), returned in x's dtype.
torch::Tensor bias_gelu_reference(const torch::Tensor& x, const torch::Tensor& b);

}  // namespace ablenerf
