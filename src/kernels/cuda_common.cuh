#pragma once
// Device helpers shared by the CUDA kernels of this folder: loads and stores that convert between
// the storage type (float or bfloat16) and float arithmetic, a warp sum and maximum, and the deterministic
// column sums that turn per-block partial results into parameter gradients. CUDA headers only.
#include <cuda_bf16.h>
#include <cuda_runtime.h>

#include <cstdint>

namespace ablenerf::cuda_detail {

constexpr int kWarp = 32;

__device__ __forceinline__ float load(const float* p, int64_t i) { return p[i]; }
__device__ __forceinline__ float load(const __nv_bfloat16* p, int64_t i) { return __bfloat162float(p[i]); }
__device__ __forceinline__ void store(float* p, int64_t i, float v) { p[i] = v; }
// Round to nearest even, as ATen's float -> bfloat16 conversion does.
__device__ __forceinline__ void store(__nv_bfloat16* p, int64_t i, float v) { p[i] = __float2bfloat16_rn(v); }

// The sum of v over the 32 lanes of a warp, returned to every lane. The butterfly order is fixed,
// so the result does not depend on timing.
__device__ __forceinline__ float warp_sum(float v) {
#pragma unroll
  for (int offset = kWarp / 2; offset > 0; offset /= 2) v += __shfl_xor_sync(0xffffffffu, v, offset);
  return v;
}

// The maximum of v over the 32 lanes of a warp, returned to every lane.
__device__ __forceinline__ float warp_max(float v) {
#pragma unroll
  for (int offset = kWarp / 2; offset > 0; offset /= 2) v = fmaxf(v, __shfl_xor_sync(0xffffffffu, v, offset));
  return v;
}

// out[c] = sum over p in [0, parts) of partial[p * cols + c], added in the order of p: one thread
// per column, so the result is the same on every run (unlike atomics).
template <int kUnused = 0>
__global__ void column_sums_kernel(const float* __restrict__ partial, int parts, int cols, float* __restrict__ out) {
  const int c = blockIdx.x * blockDim.x + threadIdx.x;
  if (c >= cols) return;
  float total = 0.f;
  for (int p = 0; p < parts; ++p) total += partial[int64_t(p) * cols + c];
  out[c] = total;
}

// Launches column_sums_kernel on stream (nothing when cols == 0).
inline void launch_column_sums(const float* partial, int parts, int cols, float* out, cudaStream_t stream) {
  constexpr int kThreads = 256;
  if (cols == 0) return;
  column_sums_kernel<<<(cols + kThreads - 1) / kThreads, kThreads, 0, stream>>>(partial, parts, cols, out);
}

}  // namespace ablenerf::cuda_detail
