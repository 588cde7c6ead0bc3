#pragma once
// Launches of the fused bias + exact GELU kernels (bias_gelu_cuda.cu) on raw device pointers and a
// stream. CUDA headers only, so that nvcc compiles the kernels without LibTorch. x, y, dy, dx:
// contiguous row-major (rows, cols), float or bfloat16 (all of one call alike); the bias, its
// gradient and all arithmetic are float.
#include <cuda_bf16.h>
#include <cuda_runtime.h>

#include <cstddef>
#include <cstdint>

namespace ablenerf {

// y = gelu(x + b) with the exact GELU: gelu(z) = z * Phi(z) = z / 2 * (1 + erf(z / sqrt(2))).
cudaError_t launch_bias_gelu_forward(const float* x, const float* b, int64_t rows, int cols, float* y,
                                     cudaStream_t stream);
cudaError_t launch_bias_gelu_forward(const __nv_bfloat16* x, const float* b, int64_t rows, int cols, __nv_bfloat16* y,
                                     cudaStream_t stream);

// Floats of scratch that the backward launch needs (per-block partial column sums of db).
size_t bias_gelu_backward_workspace(int64_t rows, int cols);

// dx = dy * gelu'(x + b), gelu'(z) = Phi(z) + z * phi(z) (phi the standard normal density), and
// db (cols) = column sums of dx taken in float before any rounding of dx, added in a fixed order
// (the same on every run). workspace: bias_gelu_backward_workspace() floats.
cudaError_t launch_bias_gelu_backward(const float* dy, const float* x, const float* b, int64_t rows, int cols,
                                      float* dx, float* db, float* workspace, cudaStream_t stream);
cudaError_t launch_bias_gelu_backward(const __nv_bfloat16* dy, const __nv_bfloat16* x, const float* b, int64_t rows,
                                      int cols, __nv_bfloat16* dx, float* db, float* workspace, cudaStream_t stream);

}  // namespace ablenerf
