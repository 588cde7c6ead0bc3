#pragma once
// The tail of a post-norm transformer block, everything after the attention core, as one
// operation with its own backward (CPU, float32):
//
//   h = LN1(x + heads Wo^T + bo)                     output projection, residual, LayerNorm
//   y = LN2(h + W2 GELU(W1 h + b1) + b2)             feed-forward (exact GELU), residual, LayerNorm
//
// x: the block's residual input (Bx, L, E) with Bx == B or 1 (queries shared by every ray: the
// LE's cross-attention); heads: the attention core's concatenated heads (B, L, E), before the
// output projection. Returns y (B, L, E).
//
// Why: on a CPU training step the model's blocks are narrow (E = 32, F = 64 at the capture preset)
// and short (17 tokens a ray), so the ten autograd nodes of the plain tail (three linears, two
// adds, two LayerNorms, GELU, and their temporaries) cost more in dispatch, allocation and memory
// traffic than in arithmetic. Here rows (tokens) go through the whole tail a chunk at a time while
// they stay in cache: products by kernels/small_gemm.h, GELU and its derivative in one pass by
// kernels/gelu_cpu.h (Sleef's vector erf and exp), LayerNorm written out per row. The backward
// keeps LN1's and LN2's normalised rows, the GELU's output and its derivative, and both LayerNorms'
// reciprocal deviations (2E + 2F + 2 floats per token), recomputes h from them and evaluates no
// erf or exp. Mathematics of the reference below; only summation order and rounding differ.
#include <torch/torch.h>

#include "kernels/cpu_features.h"

namespace ablenerf {

// The block's parameters, as its modules hold them: Linear weights (out, in).
struct BlockTailWeights {
  torch::Tensor out_weight, out_bias;        // (E, E), (E): the attention's output projection
  torch::Tensor norm1_weight, norm1_bias;    // (E)
  torch::Tensor ff_in_weight, ff_in_bias;    // (F, E), (F)
  torch::Tensor ff_out_weight, ff_out_bias;  // (E, F), (E)
  torch::Tensor norm2_weight, norm2_bias;    // (E)
};

// True when block_tail runs on these: CPU float32 activations and parameters.
bool block_tail_available(const torch::Tensor& x, const torch::Tensor& heads, const BlockTailWeights& w);

// Differentiable in x, heads and every weight. `chunk_rows` (> 0) sets the tokens taken through the
// tail at a time (0: the default, sized so that a chunk's rows stay in a core's L2 cache). `form`:
// the instruction form of the row loops (LayerNorms, residuals, biases; the tests run each one this
// CPU has). Throws c10::Error naming "block_tail" and the argument on a bad shape, dtype or device,
// or a form this CPU does not run.
torch::Tensor block_tail(const torch::Tensor& x, const torch::Tensor& heads, const BlockTailWeights& w, double eps,
                         int64_t chunk_rows = 0, CpuVectorForm form = cpu_best_vector_form());

// The plain LibTorch version the kernel is tested against (any dtype and device).
torch::Tensor block_tail_reference(const torch::Tensor& x, const torch::Tensor& heads, const BlockTailWeights& w,
                                   double eps);

}  // namespace ablenerf
