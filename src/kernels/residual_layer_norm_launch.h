#pragma once
// Launches of the fused residual add + LayerNorm kernels (residual_layer_norm_cuda.cu) on raw
// device pointers and a stream. CUDA headers only, so that nvcc compiles the kernels without
// LibTorch. Every array is contiguous and row-major: `rows` rows of `width` values, width a
// multiple of 32 and at most 1024 (one warp per row, width / 32 values per lane). Activations are
// float or bfloat16 (both of one call alike); gamma, beta, the statistics and the parameter
// gradients are float; all arithmetic is in float.
#include <cuda_bf16.h>
#include <cuda_runtime.h>

#include <cstddef>
#include <cstdint>

namespace ablenerf {

// Widths the kernels take: multiples of 32 in [32, kResidualLayerNormMaxWidth].
constexpr int kResidualLayerNormMaxWidth = 1024;
constexpr bool residual_layer_norm_width_supported(int64_t width) {
  return width >= 32 && width <= kResidualLayerNormMaxWidth && width % 32 == 0;
}

// s = x + r;  y = (s - mean(s)) * rstd * gamma + beta,  rstd = 1 / sqrt(var(s) + eps), per row
// (biased variance, as LayerNorm). mean and rstd (rows) receive the row statistics for backward.
// Returns cudaErrorInvalidValue for an unsupported width, else the launch's status.
cudaError_t launch_residual_layer_norm_forward(const float* x, const float* r, const float* gamma, const float* beta,
                                               int64_t rows, int width, float eps, float* y, float* mean, float* rstd,
                                               cudaStream_t stream);
cudaError_t launch_residual_layer_norm_forward(const __nv_bfloat16* x, const __nv_bfloat16* r, const float* gamma,
                                               const float* beta, int64_t rows, int width, float eps, __nv_bfloat16* y,
                                               float* mean, float* rstd, cudaStream_t stream);

// Floats of scratch that the backward launch needs (per-block partial sums of dgamma, dbeta).
size_t residual_layer_norm_backward_workspace(int64_t rows, int width);

// From dy and the forward's inputs and statistics: ds = dL/ds (the gradient of x and of r alike),
// and dgb = [dgamma | dbeta] (2 * width floats: column sums over rows, added in a fixed order, so
// they are the same on every run). workspace: residual_layer_norm_backward_workspace() floats.
cudaError_t launch_residual_layer_norm_backward(const float* dy, const float* x, const float* r, const float* gamma,
                                                const float* mean, const float* rstd, int64_t rows, int width,
                                                float* ds, float* dgb, float* workspace, cudaStream_t stream);
cudaError_t launch_residual_layer_norm_backward(const __nv_bfloat16* dy, const __nv_bfloat16* x, const __nv_bfloat16* r,
                                                const float* gamma, const float* mean, const float* rstd, int64_t rows,
                                                int width, __nv_bfloat16* ds, float* dgb, float* workspace,
                                                cudaStream_t stream);

}  // namespace ablenerf
