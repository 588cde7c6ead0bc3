#pragma once
// The scaled dot-product core of multi-head attention, softmax(Q K^T * scale + mask) V, on the
// CPU, read straight from the packed projections that nn.MultiheadAttention-style layers produce:
//   self-attention:  qkv (B, L, 3E) = [Q | K | V] per token, heads side by side inside each E;
//   cross-attention: q (Bq, Lq, E) with Bq == B or 1 (queries shared by the batch), kv (B, Lk, 2E).
// The result is (B, Lq, E) with the heads already concatenated, ready for the output projection.
//
// Why: the model runs one small product per ray and head (97 x 64 x 97 at the blender preset).
// Through LibTorch 1.13 that means copying Q, K and V into per-head layouts, a batched matmul
// that dispatches every small product separately, and a copy back; OpenBLAS's own thread pool
// then synchronises inside every one of them. Here each product reads the strided operands in
// place (no copies): products with every dimension <= 64 (17 x 17 x 24 at the demo preset) run
// register-blocked loops (kernels/small_gemm.h; a BLAS call costs more than their arithmetic),
// larger ones one single-threaded BLAS call each; float softmax exponentials go through
// kernels/vector_exp.h; the batch is split across CPU threads (kernels/cpu_parallel.h), and a
// hand-written backward does the same. The mathematics are those of the reference formula; only
// the summation order and rounding inside the products and exp differ.
#include <torch/torch.h>

#include "kernels/cpu_features.h"

namespace ablenerf {

// True when these kernels can run on x: a CPU float32/float64 tensor and a BLAS providing
// cblas_sgemm / cblas_dgemm in the process (found at run time).
bool packed_attention_available(const torch::Tensor& x);

// mask: additive (Lq, Lk), broadcast over rays and heads, or undefined. Differentiable. `form`:
// with Avx512 (on a CPU that runs it, in float32, heads of at most 64 and at most 64 queries and
// keys) each (ray, head) is computed whole, its scores and softmax in vector registers, the
// backward likewise; otherwise, and always with Scalar, the products described above.
torch::Tensor packed_self_attention(const torch::Tensor& qkv, int64_t heads, const torch::Tensor& mask, double scale,
                                    CpuVectorForm form = cpu_best_vector_form());
torch::Tensor packed_cross_attention(const torch::Tensor& q, const torch::Tensor& kv, int64_t heads, double scale,
                                     CpuVectorForm form = cpu_best_vector_form());

// The same, and the first query's probabilities over every key (B, H, Lk), the ray token's row the
// resampler and the attention's losses read; both differentiable. For cross-attention the queries
// are per ray here (q's batch is kv's).
struct PackedAttention {
  torch::Tensor out, row0;
};
PackedAttention packed_self_attention_row0(const torch::Tensor& qkv, int64_t heads, const torch::Tensor& mask,
                                           double scale, CpuVectorForm form = cpu_best_vector_form());
PackedAttention packed_cross_attention_row0(const torch::Tensor& q, const torch::Tensor& kv, int64_t heads,
                                            double scale, CpuVectorForm form = cpu_best_vector_form());

}  // namespace ablenerf
