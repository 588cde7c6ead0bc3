#pragma once
// The scaled dot-product core of attention, softmax(Q K^T * scale + mask) V, over a batch of
// many small matrices (one per ray and head: 97 x 64 at the blender preset).
//
// Why not plain bmm: LibTorch 1.13's CPU bmm loops over the batch and hands every small
// product to the BLAS, whose own thread pool (OpenBLAS-pthreads: 2 threads here) then
// synchronises once per 1 MFLOP product. Profiling the blender forward showed those products
// taking ~70% of the wall time while being ~8% of the FLOPs. Here the batch is split across
// CPU threads instead, each running single-threaded BLAS products, and a custom autograd
// function gives the backward the same treatment. The mathematics are unchanged (same
// products, same softmax); only the summation order inside the BLAS may differ.
#include <torch/torch.h>

namespace ablenerf {

// q: (N,Lq,dh), k, v: (N,Lk,dh), mask: additive (Lq,Lk) broadcast over N, or undefined.
// Returns (N,Lq,dh). Differentiable in q, k and v.
torch::Tensor attention_core(const torch::Tensor& q, const torch::Tensor& k, const torch::Tensor& v,
                             const torch::Tensor& mask, double scale);

// out = a @ b for (N,m,k) x (N,k,n), batch split across CPU threads (plain bmm elsewhere).
torch::Tensor batched_matmul(const torch::Tensor& a, const torch::Tensor& b);

}  // namespace ablenerf
