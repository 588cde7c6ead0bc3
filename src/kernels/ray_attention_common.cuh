#pragma once
// What the fused ray attention kernels share (ray_attention_fp32_cuda.cu, ray_attention_bf16_cuda.cu):
// the head size, the ray mask's last visible column, warp reductions, cp.async loads, and the
// launch helpers. Included by those .cu files only.
#include <cuda_bf16.h>
#include <math_constants.h>

#include "kernels/cuda_common.cuh"
#include "kernels/ray_attention_launch.h"

namespace ablenerf::kernels::ray_attention_detail {

inline constexpr int kDh = kRayAttentionHeadDim;
inline constexpr unsigned kFullMask = 0xffffffffu;

// The last column row i may attend to.
__device__ __forceinline__ int last_column(int i, int tokens, bool masked) { return masked && i > 0 ? i : tokens - 1; }

using cuda_detail::warp_max;
using cuda_detail::warp_sum;

// Asynchronous copy of N (4 or 16) bytes from global to shared memory (cp.async, sm_80+), or of N
// zero bytes when !valid (src is then not read, but must still be a mapped address). Every thread
// issues all of its copies before waiting, so that the block's loads are in flight together.
template <int N>
__device__ __forceinline__ void copy_async(void* dst, const void* src, bool valid) {
  static_assert(N == 4 || N == 16, "cp.async copies 4 or 16 bytes here");
  const unsigned d = static_cast<unsigned>(__cvta_generic_to_shared(dst));
  if constexpr (N == 16) {
    asm volatile("cp.async.cg.shared.global [%0], [%1], 16, %2;\n" ::"r"(d), "l"(src), "r"(valid ? 16 : 0) : "memory");
  } else {
    asm volatile("cp.async.ca.shared.global [%0], [%1], 4, %2;\n" ::"r"(d), "l"(src), "r"(valid ? 4 : 0) : "memory");
  }
}

// Waits for this thread's copies; a barrier must follow before other threads read them.
__device__ __forceinline__ void copy_async_wait() { asm volatile("cp.async.wait_all;\n" ::: "memory"); }

// Shared memory beyond 48 KB must be granted per kernel before launch.
template <class Kernel>
cudaError_t grant_smem(Kernel kernel, size_t bytes) {
  return cudaFuncSetAttribute(kernel, cudaFuncAttributeMaxDynamicSharedMemorySize, int(bytes));
}

inline float softmax_scale() { return 1.f / sqrtf(float(kDh)); }

}  // namespace ablenerf::kernels::ray_attention_detail
