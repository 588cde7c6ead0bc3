#pragma once
// Launches of the fused ray self-attention kernels (ray_attention_fp32_cuda.cu, ray_attention_bf16_cuda.cu), on raw
// device pointers and a stream, so that plain nvcc compiles the kernels without LibTorch. The checked ATen-level entry
// points are in kernels/ray_attention.h.
//
// Layout (B rays, L tokens, H heads of kRayAttentionHeadDim = 64, E = 64 H), all contiguous:
//   qkv       (B, L, 3E): per token [Q | K | V], head h of Q at columns [64h, 64h + 64),
//                         of K at E + 64h, of V at 2E + 64h;
//   out       (B, L, E):  softmax(Q K^T / sqrt(64) + M) V per ray and head, heads side by side;
//   lse       (B, H, L) fp32: each row's log-sum-exp of the scaled, masked scores (for backward);
//   row0      (B, H, L) fp32: row 0's probabilities (the ray token's attention over the tokens);
//   grad_out  (B, L, E) and grad_qkv (B, L, 3E): the gradients, same layouts (every element of
//                         grad_qkv is written).
// M, when `masked`: row 0 sees every column, row i >= 1 sees columns 0..i (no row is ever fully
// blocked, column 0 is always visible).
// Scores, softmax and every product accumulate in fp32; bf16 inputs use tensor cores (bf16 x bf16
// -> fp32), fp32 inputs CUDA cores. bf16 pointers must be 16-byte aligned.
// Each launch returns the first CUDA error (cudaErrorInvalidValue for a shape outside the
// supported range), without synchronising.
#include <cuda_bf16.h>
#include <cuda_runtime_api.h>

#include <cstdint>

namespace ablenerf::kernels {

constexpr int kRayAttentionHeadDim = 64;
constexpr int kRayAttentionMaxTokens = 128;

struct RayAttentionShape {
  int64_t batch = 0;  // B; B * heads must fit in an int
  int tokens = 0;     // L in [1, kRayAttentionMaxTokens]
  int heads = 0;      // H >= 1
  bool masked = false;
};

// True when the kernels accept this shape (batch 0 is accepted and launches nothing).
bool ray_attention_shape_supported(const RayAttentionShape& shape);

cudaError_t launch_ray_attention_forward(const float* qkv, float* out, float* lse, float* row0,
                                         const RayAttentionShape& shape, cudaStream_t stream);
cudaError_t launch_ray_attention_forward(const __nv_bfloat16* qkv, __nv_bfloat16* out, float* lse, float* row0,
                                         const RayAttentionShape& shape, cudaStream_t stream);

// out and lse are the forward's results for the same qkv.
cudaError_t launch_ray_attention_backward(const float* qkv, const float* out, const float* grad_out, const float* lse,
                                          float* grad_qkv, const RayAttentionShape& shape, cudaStream_t stream);
cudaError_t launch_ray_attention_backward(const __nv_bfloat16* qkv, const __nv_bfloat16* out,
                                          const __nv_bfloat16* grad_out, const float* lse, __nv_bfloat16* grad_qkv,
                                          const RayAttentionShape& shape, cudaStream_t stream);

}  // namespace ablenerf::kernels
