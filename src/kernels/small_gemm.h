#pragma once
// Products of row-major matrices with few columns on the CPU, written out in registers:
//
//   C (m x n, row stride ldc) = alpha * op(A) * B
//   op(A)(i, p) = A[i * lda + p], or with trans_a A[p * lda + i]  (m x k)
//   B (k x n): B[p * ldb + j]
//
// C is overwritten (no beta). Rows of C are taken four at a time, their columns in blocks of up to
// three or four SIMD vectors held in registers over the whole reduction; on x86-64 CPUs the widest
// vector form the CPU runs is chosen at run time (SmallGemmForm below), elsewhere the same code runs
// with the baseline instructions. Each element is sum_p op(A)(i, p) B(p, j) in increasing p, then times alpha: only
// rounding (FMA contraction) can differ from a plain loop.
//
// Any sizes >= 1 are computed; it pays off where n and k are small:
//  - the attention core's per-(ray, head) products (17 x 17 x 24 at the demo preset), where one BLAS
//    call costs ~1 us of argument checks and packing against ~0.1 us of arithmetic
//    (small_gemm_fits: every dimension <= 64);
//  - the token linear layers' forward and input gradient (kernels/linear_cpu.h: m in the
//    thousands, n and k 48-192), where it measured ~1.4x OpenBLAS's sgemm.
#include <cstdint>

#include "kernels/aligned_buffer.h"

namespace ablenerf {

// Attention's criterion: every dimension at most this (larger products go to BLAS).
constexpr int64_t kSmallGemmMaxDim = 64;
inline bool small_gemm_fits(int64_t m, int64_t n, int64_t k) {
  return m > 0 && n > 0 && k > 0 && m <= kSmallGemmMaxDim && n <= kSmallGemmMaxDim && k <= kSmallGemmMaxDim;
}

void small_gemm(bool trans_a, int64_t m, int64_t n, int64_t k, float alpha, const float* a, int64_t lda, const float* b,
                int64_t ldb, float* c, int64_t ldc);
void small_gemm(bool trans_a, int64_t m, int64_t n, int64_t k, double alpha, const double* a, int64_t lda,
                const double* b, int64_t ldb, double* c, int64_t ldc);

// Row-major transpose: dst (cols x rows, row stride rows) = src (rows x cols, row stride lds)^T.
// For C = A B^T with small_gemm: transpose B once into a scratch.
// In tiles of 16 x 16, so that a large matrix (the paper's 576 x 192 feed-forward weights) is read
// and written a cache line at a time rather than one strided element after another.
template <class T>
void transpose_into(const T* src, int64_t rows, int64_t cols, int64_t lds, T* dst) {
  constexpr int64_t kTile = 16;
  for (int64_t r0 = 0; r0 < rows; r0 += kTile)
    for (int64_t c0 = 0; c0 < cols; c0 += kTile) {
      const int64_t r1 = r0 + kTile < rows ? r0 + kTile : rows, c1 = c0 + kTile < cols ? c0 + kTile : cols;
      for (int64_t r = r0; r < r1; ++r)
        for (int64_t c = c0; c < c1; ++c) dst[c * rows + r] = src[r * lds + c];
    }
}

// The instruction forms small_gemm chooses from at run time, the widest this CPU runs: AVX-512
// (16 floats per vector), AVX2 + FMA (8), or the baseline instructions (the same code, any x86-64
// or other CPU). Each computes the same sums; only rounding (FMA contraction) can differ.
enum class SmallGemmForm { Avx512, Avx2, Baseline };
bool small_gemm_form_available(SmallGemmForm form);
SmallGemmForm small_gemm_best_form();
// small_gemm in a given form (the tests run every one this CPU has); throws c10::Error for a form
// the CPU does not run.
void small_gemm_in(SmallGemmForm form, bool trans_a, int64_t m, int64_t n, int64_t k, float alpha, const float* a,
                   int64_t lda, const float* b, int64_t ldb, float* c, int64_t ldc);
void small_gemm_in(SmallGemmForm form, bool trans_a, int64_t m, int64_t n, int64_t k, double alpha, const double* a,
                   int64_t lda, const double* b, int64_t ldb, double* c, int64_t ldc);

}  // namespace ablenerf
