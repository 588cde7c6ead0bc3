#include "kernels/small_gemm.h"

#include <c10/util/Exception.h>

#include <algorithm>
#include <cstring>
#include <type_traits>
#include <vector>

#include "kernels/cpu_features.h"

namespace ablenerf {

namespace {

// SIMD vectors of `Bytes` bytes (GCC/Clang vector extensions): 32 is one AVX register (two SSE
// registers without AVX), 64 one AVX-512 register. `unaligned`: the same vector at any element
// address (loads and stores of rows of C and B). `wide_block`: vectors per block of four rows (with
// AVX, twelve accumulators, three B vectors and a broadcast fill its sixteen registers; AVX-512's
// thirty-two take sixteen accumulators).
template <class T, int Bytes, int WideBlock>
struct Vectors {
  using scalar = T;
  typedef T vec __attribute__((vector_size(Bytes)));
  typedef T unaligned __attribute__((vector_size(Bytes), aligned(sizeof(T)), may_alias));
  static constexpr int lanes = Bytes / static_cast<int>(sizeof(T));
  static constexpr int wide_block = WideBlock;
};
using F8 = Vectors<float, 32, 3>;
using D4 = Vectors<double, 32, 3>;
using F16 = Vectors<float, 64, 4>;
using D8 = Vectors<double, 64, 4>;

// NR rows x NV vectors of C, accumulated over the whole reduction in registers. Row r of op(A)
// starts at a + r * si; consecutive p are sp apart. b and c point at the block's first column.
// With TAIL the last vector holds the r < lanes columns left after the whole vectors: it loads
// from bt (those columns of B packed k x lanes, zeros after column r) and stores r columns only.
template <class S, int NR, int NV, bool TAIL>
ABLENERF_ALWAYS_INLINE void tile(int64_t k, typename S::scalar alpha, const typename S::scalar* a, int64_t sp,
                                 int64_t si, const typename S::scalar* b, int64_t ldb, const typename S::scalar* bt,
                                 typename S::scalar* c, int64_t ldc, int64_t r) {
  using T = typename S::scalar;
  using V = typename S::vec;
  using U = typename S::unaligned;
  constexpr int64_t W = S::lanes;
  V acc[NR][NV];
  for (int i = 0; i < NR; ++i)
    for (int v = 0; v < NV; ++v) acc[i][v] = V{};
  for (int64_t p = 0; p < k; ++p) {
    V bv[NV];
    for (int v = 0; v < NV; ++v)
      bv[v] = TAIL && v == NV - 1 ? *reinterpret_cast<const U*>(bt + p * W)
                                  : *reinterpret_cast<const U*>(b + p * ldb + v * W);
    for (int i = 0; i < NR; ++i) {
      const T x = a[i * si + p * sp];
      for (int v = 0; v < NV; ++v) acc[i][v] += x * bv[v];
    }
  }
  for (int i = 0; i < NR; ++i)
    for (int v = 0; v < NV; ++v) {
      if (TAIL && v == NV - 1) {
        T out[W];
        *reinterpret_cast<U*>(out) = acc[i][v] * alpha;
        std::memcpy(c + i * ldc + v * W, out, static_cast<size_t>(r) * sizeof(T));
      } else {
        *reinterpret_cast<U*>(c + i * ldc + v * W) = acc[i][v] * alpha;
      }
    }
}

// NR rows of C, all n columns, in blocks of up to four vectors (S::wide_block for four rows); the
// columns after the last whole vector join the last block (see tile's TAIL).
template <class S, int NR>
ABLENERF_ALWAYS_INLINE void rows(int64_t n, int64_t k, typename S::scalar alpha, const typename S::scalar* a,
                                 int64_t sp, int64_t si, const typename S::scalar* b, int64_t ldb,
                                 const typename S::scalar* bt, typename S::scalar* c, int64_t ldc) {
  constexpr int64_t W = S::lanes;
  constexpr int64_t kBlock = NR >= 4 ? S::wide_block : 4;
  const int64_t tail = n % W, vectors = n / W + (tail > 0 ? 1 : 0);
  for (int64_t v0 = 0; v0 < vectors; v0 += kBlock) {
    const int64_t nv = std::min(kBlock, vectors - v0);
    const bool last = v0 + nv == vectors && tail > 0;
    const int64_t j = v0 * W;
    switch (nv * 2 + (last ? 1 : 0)) {
#define ABLENERF_GEMM_CASE(NV, TAIL) \
  case NV * 2 + TAIL: tile<S, NR, NV, TAIL>(k, alpha, a, sp, si, b + j, ldb, bt, c + j, ldc, tail); break;
      ABLENERF_GEMM_CASE(1, 0)
      ABLENERF_GEMM_CASE(1, 1)
      ABLENERF_GEMM_CASE(2, 0)
      ABLENERF_GEMM_CASE(2, 1)
      ABLENERF_GEMM_CASE(3, 0)
      ABLENERF_GEMM_CASE(3, 1)
      ABLENERF_GEMM_CASE(4, 0)
      ABLENERF_GEMM_CASE(4, 1)
#undef ABLENERF_GEMM_CASE
      default: break;
    }
  }
}

template <class S>
ABLENERF_ALWAYS_INLINE void gemm_body(bool trans_a, int64_t m, int64_t n, int64_t k, typename S::scalar alpha,
                                      const typename S::scalar* a, int64_t lda, const typename S::scalar* b,
                                      int64_t ldb, typename S::scalar* c, int64_t ldc) {
  using T = typename S::scalar;
  constexpr int64_t W = S::lanes;
  const int64_t sp = trans_a ? lda : 1, si = trans_a ? 1 : lda;
  // The columns after the last whole vector, packed once for every row (zeros after them).
  const int64_t tail = n % W, first = n - tail;
  T stack_bt[kSmallGemmMaxDim * W];
  std::vector<T> heap_bt(tail > 0 && k > kSmallGemmMaxDim ? static_cast<size_t>(k * W) : 0);
  T* bt = heap_bt.empty() ? stack_bt : heap_bt.data();
  if (tail > 0) {
    std::fill(bt, bt + k * W, T(0));
    for (int64_t p = 0; p < k; ++p)
      for (int64_t j = 0; j < tail; ++j) bt[p * W + j] = b[p * ldb + first + j];
  }
  // Four rows at a time (independent accumulators hide the FMA latency), then two, then one.
  int64_t i = 0;
  for (; i + 4 <= m; i += 4) rows<S, 4>(n, k, alpha, a + i * si, sp, si, b, ldb, bt, c + i * ldc, ldc);
  if (i + 2 <= m) {
    rows<S, 2>(n, k, alpha, a + i * si, sp, si, b, ldb, bt, c + i * ldc, ldc);
    i += 2;
  }
  if (i < m) rows<S, 1>(n, k, alpha, a + i * si, sp, si, b, ldb, bt, c + i * ldc, ldc);
}

}  // namespace

namespace {

#ifdef ABLENERF_HAVE_AVX2_FORM
ABLENERF_TARGET_AVX512 void gemm_avx512(bool ta, int64_t m, int64_t n, int64_t k, float alpha, const float* a,
                                        int64_t lda, const float* b, int64_t ldb, float* c, int64_t ldc) {
  gemm_body<F16>(ta, m, n, k, alpha, a, lda, b, ldb, c, ldc);
}
ABLENERF_TARGET_AVX512 void gemm_avx512(bool ta, int64_t m, int64_t n, int64_t k, double alpha, const double* a,
                                        int64_t lda, const double* b, int64_t ldb, double* c, int64_t ldc) {
  gemm_body<D8>(ta, m, n, k, alpha, a, lda, b, ldb, c, ldc);
}
ABLENERF_TARGET_AVX2 void gemm_avx2(bool ta, int64_t m, int64_t n, int64_t k, float alpha, const float* a, int64_t lda,
                                    const float* b, int64_t ldb, float* c, int64_t ldc) {
  gemm_body<F8>(ta, m, n, k, alpha, a, lda, b, ldb, c, ldc);
}
ABLENERF_TARGET_AVX2 void gemm_avx2(bool ta, int64_t m, int64_t n, int64_t k, double alpha, const double* a,
                                    int64_t lda, const double* b, int64_t ldb, double* c, int64_t ldc) {
  gemm_body<D4>(ta, m, n, k, alpha, a, lda, b, ldb, c, ldc);
}
#endif

// Unchecked: the form must be one this CPU runs.
template <class T>
void run_form(SmallGemmForm form, bool ta, int64_t m, int64_t n, int64_t k, T alpha, const T* a, int64_t lda,
              const T* b, int64_t ldb, T* c, int64_t ldc) {
  switch (form) {
#ifdef ABLENERF_HAVE_AVX2_FORM
    case SmallGemmForm::Avx512: return gemm_avx512(ta, m, n, k, alpha, a, lda, b, ldb, c, ldc);
    case SmallGemmForm::Avx2: return gemm_avx2(ta, m, n, k, alpha, a, lda, b, ldb, c, ldc);
#endif
    default:
      return gemm_body<std::conditional_t<std::is_same<T, float>::value, F8, D4>>(ta, m, n, k, alpha, a, lda, b, ldb, c,
                                                                                  ldc);
  }
}

}  // namespace

bool small_gemm_form_available(SmallGemmForm form) {
  switch (form) {
    case SmallGemmForm::Avx512: return cpu_has_avx512();
    case SmallGemmForm::Avx2: return cpu_has_avx2_fma();
    case SmallGemmForm::Baseline: return true;
  }
  return false;
}

SmallGemmForm small_gemm_best_form() {
  static const SmallGemmForm best = cpu_has_avx512()     ? SmallGemmForm::Avx512
                                    : cpu_has_avx2_fma() ? SmallGemmForm::Avx2
                                                         : SmallGemmForm::Baseline;
  return best;
}

void small_gemm_in(SmallGemmForm form, bool trans_a, int64_t m, int64_t n, int64_t k, float alpha, const float* a,
                   int64_t lda, const float* b, int64_t ldb, float* c, int64_t ldc) {
  TORCH_CHECK(small_gemm_form_available(form), "small_gemm: this CPU does not run the requested form");
  run_form(form, trans_a, m, n, k, alpha, a, lda, b, ldb, c, ldc);
}
void small_gemm_in(SmallGemmForm form, bool trans_a, int64_t m, int64_t n, int64_t k, double alpha, const double* a,
                   int64_t lda, const double* b, int64_t ldb, double* c, int64_t ldc) {
  TORCH_CHECK(small_gemm_form_available(form), "small_gemm: this CPU does not run the requested form");
  run_form(form, trans_a, m, n, k, alpha, a, lda, b, ldb, c, ldc);
}

void small_gemm(bool trans_a, int64_t m, int64_t n, int64_t k, float alpha, const float* a, int64_t lda, const float* b,
                int64_t ldb, float* c, int64_t ldc) {
  run_form(small_gemm_best_form(), trans_a, m, n, k, alpha, a, lda, b, ldb, c, ldc);
}
void small_gemm(bool trans_a, int64_t m, int64_t n, int64_t k, double alpha, const double* a, int64_t lda,
                const double* b, int64_t ldb, double* c, int64_t ldc) {
  run_form(small_gemm_best_form(), trans_a, m, n, k, alpha, a, lda, b, ldb, c, ldc);
}

}  // namespace ablenerf
