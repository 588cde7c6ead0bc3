#pragma once
// y = x W^T + b for the model's token matrices on the CPU in float32, differentiable, as one
// autograd node:
//   forward      y  = x W^T (+ b)  register-blocked loops (kernels/small_gemm.h) over W^T, bias added
//                                  per row;
//   backward     dx = dy W         the same loops;
//                dW = dy^T x       the same loops, each 4 x 64 block of dW summed over all tokens in
//                                  registers (one thread at 2,176 x 32-96 x 32-64: 98-118 GFLOP/s
//                                  against OpenBLAS's sgemm 64-93);
//                db = column sums of dy, a block of rows at a time (linear_cpu.cpp);
//   the bias, the ReLU, its gradient and the column sums in loops compiled for AVX-512 as well as
//   the baseline, chosen at run time.
// With compute.precision = "bf16" on a CPU with AMX (kernels/token_product.h: the thread's setting
// when the forward runs, kept for its backward), y, dx and dW take bfloat16 operands with float32
// sums (kernels/bf16_gemm.h); db and everything else stay float32.
// Why: at the demo preset (2,176 tokens per 128-ray slice, 48-144 features) OpenBLAS's sgemm spends
// a large share of each call packing operands (measured ~1.4x slower than the loops for x W^T), and
// LibTorch's addmm path adds reshape / t / view nodes to every layer's forward and backward.
#include <torch/torch.h>

#include "kernels/cpu_features.h"

namespace ablenerf {

// True when linear_cpu runs on these: CPU float32 x (..., K) with at least two dimensions (a matrix
// or tokens) and weight (N, K).
bool linear_cpu_available(const torch::Tensor& x, const torch::Tensor& weight);

// x (..., K), weight (N, K), bias (N) or undefined -> (..., N): x's rows as one (M, K) matrix inside
// the node, so that tokens need no reshape nodes around it. Differentiable in all three. With
// `relu`, max(y, 0) in the same node: applied to each row after its bias, and in the backward the
// output gradient kept where y > 0 (torch::relu's forward and backward, one node and one pass less).
// `form` picks the element-wise passes' instructions (the bias, the ReLU and its gradient, the bias's
// gradient); every form gives the same bits (the tests force the scalar one).
torch::Tensor linear_cpu(const torch::Tensor& x, const torch::Tensor& weight, const torch::Tensor& bias,
                         bool relu = false, CpuVectorForm form = cpu_best_vector_form());

}  // namespace ablenerf
