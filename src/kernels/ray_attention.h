#pragma once
// Self-attention of the AB transformer over the tokens of each ray, read straight from the packed
// projection, with the ray token's attention row as a by-product.
//
//   qkv:  (B, L, 3E), per token [Q | K | V], heads side by side inside each E (head h of Q is
//         columns [h dh, (h + 1) dh), of K [E + h dh, ...), of V [2E + h dh, ...)).
//   out:  (B, L, E), same dtype, heads concatenated (ready for the output projection):
//         per ray and head softmax(Q K^T / sqrt(dh) + M) V, accumulated in fp32 (or float64).
//   row0: (B, H, L), row 0's softmax probabilities (the ray token's attention over the tokens),
//         float32 (float64 for a float64 reference); never differentiated.
// M, when `masked`: row 0 (the ray token) sees every column, row i >= 1 sees columns 0..i
// (blocked entries are -inf; column 0 is always visible, so no row is ever fully blocked).
//
// ray_attention runs the fused CUDA kernels (raw-pointer launches in
// kernels/ray_attention_launch.h): qkv on a CUDA device, float32 or bfloat16, dh = 64,
// 1 <= L <= 128; differentiable in qkv. Builds without ABLENERF_CUDA_KERNELS throw
// "built without CUDA kernels". ray_attention_reference is the same operation from plain LibTorch
// ops, on any device and floating dtype and any head width; the kernels are tested against it.
#include <torch/torch.h>

namespace ablenerf {

struct RayAttentionResult {
  torch::Tensor out, row0;
};

RayAttentionResult ray_attention(const torch::Tensor& qkv, int64_t heads, bool masked);

// True when ray_attention takes this shape (tokens per ray, head width) in this build: CUDA
// kernels compiled in, dh = 64, 1 <= L <= 128.
bool ray_attention_supports(int64_t tokens, int64_t head_width);

RayAttentionResult ray_attention_reference(const torch::Tensor& qkv, int64_t heads, bool masked);

}  // namespace ablenerf
