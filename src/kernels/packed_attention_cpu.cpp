#include "kernels/packed_attention.h"

#include <ATen/record_function.h>
#include <dlfcn.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "kernels/cpu_parallel.h"
#include "kernels/row_reduce.h"
#include "kernels/small_gemm.h"
#include "kernels/vector_exp.h"

#if defined(ABLENERF_HAVE_SLEEF) && defined(ABLENERF_HAVE_AVX2_FORM)
#define ABLENERF_ATTENTION_ITEMS_AVX512 1
#include <immintrin.h>
// Sleef's AVX-512 exp (see kernels/gelu_cpu.cpp on why it is declared here).
#pragma GCC push_options
#pragma GCC target("avx512f,avx2,fma")
extern "C" {
__m512 Sleef_expf16_u10avx512f(__m512);
}
#pragma GCC pop_options
#endif

namespace ablenerf {

namespace {

// Below this many (ray, head) products per thread the thread start-up costs more than it saves.
constexpr int64_t kMinItemsPerThread = 16;

// CBLAS's enumerations (cblas.h).
constexpr int kCblasRowMajor = 101, kCblasNoTrans = 111, kCblasTrans = 112;

using Sgemm = void (*)(int, int, int, int, int, int, float, const float*, int, const float*, int, float, float*, int);
using Dgemm = void (*)(int, int, int, int, int, int, double, const double*, int, const double*, int, double, double*,
                       int);

// The BLAS LibTorch itself loaded (OpenBLAS here), looked up at run time: nothing extra is linked
// and builds whose BLAS exports no CBLAS (e.g. a static MKL) fall back to the reference path.
struct Cblas {
  Sgemm s = nullptr;
  Dgemm d = nullptr;
  Cblas() {
    s = reinterpret_cast<Sgemm>(dlsym(RTLD_DEFAULT, "cblas_sgemm"));
    d = reinterpret_cast<Dgemm>(dlsym(RTLD_DEFAULT, "cblas_dgemm"));
  }
};

const Cblas& cblas() {
  static const Cblas c;
  return c;
}

// Row-major C = alpha * op(A) op(B) + beta * C.
void gemm(bool ta, bool tb, int64_t m, int64_t n, int64_t k, float alpha, const float* a, int64_t lda, const float* b,
          int64_t ldb, float beta, float* c, int64_t ldc) {
  cblas().s(kCblasRowMajor, ta ? kCblasTrans : kCblasNoTrans, tb ? kCblasTrans : kCblasNoTrans, int(m), int(n), int(k),
            alpha, a, int(lda), b, int(ldb), beta, c, int(ldc));
}
void gemm(bool ta, bool tb, int64_t m, int64_t n, int64_t k, double alpha, const double* a, int64_t lda,
          const double* b, int64_t ldb, double beta, double* c, int64_t ldc) {
  cblas().d(kCblasRowMajor, ta ? kCblasTrans : kCblasNoTrans, tb ? kCblasTrans : kCblasNoTrans, int(m), int(n), int(k),
            alpha, a, int(lda), b, int(ldb), beta, c, int(ldc));
}

// One product of the attention core, C = alpha op(A) op(B): written out in registers when small
// (kernels/small_gemm.h; B^T then goes through `scratch`), BLAS otherwise.
template <class T>
void product(bool ta, bool tb, int64_t m, int64_t n, int64_t k, T alpha, const T* a, int64_t lda, const T* b,
             int64_t ldb, T* c, int64_t ldc, std::vector<T>& scratch) {
  if (!small_gemm_fits(m, n, k)) return gemm(ta, tb, m, n, k, alpha, a, lda, b, ldb, T(0), c, ldc);
  if (tb) {
    scratch.resize(static_cast<size_t>(k * n));
    transpose_into(b, n, k, ldb, scratch.data());
    b = scratch.data();
    ldb = n;
  }
  small_gemm(ta, m, n, k, alpha, a, lda, b, ldb, c, ldc);
}

// Where one operand's heads live: the (lq or lk) x dh matrix of ray b, head h starts at
// base + b * batch + h * dh, with `row` elements between consecutive tokens.
template <class T>
struct Operand {
  T* base;
  int64_t batch, row;
  T* at(int64_t b, int64_t h, int64_t dh) const { return base + b * batch + h * dh; }
};

// Floats in one AVX-512 vector: a row chunk of the vector items, a group of rays in the ray lanes.
constexpr int64_t kLanes = 16;
// Groups of kLanes rays that hold b rays (the last one may be partly used).
int64_t lane_groups(int64_t b) { return (b + kLanes - 1) / kLanes; }

// The layout of one call: B rays, H heads of width dh, lq queries, lk keys; and its operands.
template <class T>
struct Problem {
  int64_t b, heads, dh, lq, lk;
  Operand<const T> q, k, v;
  torch::Tensor mask;  // (lq, lk) or undefined
  double scale;
  bool vector_items;  // float items in AVX-512 registers (attention_items below)
  bool lanes;         // float, sixteen rays to a vector (ray_lanes below)
  int64_t items() const { return b * heads; }
  // The probabilities' planes of lq x lk: one per item, or with lanes one per item of a whole
  // number of groups of sixteen rays (the last group's unused lanes included).
  int64_t planes() const { return lanes ? lane_units() * kLanes : items(); }
  // The ray lanes' units of work: one (group of kLanes rays, head) each.
  int64_t lane_units() const { return lane_groups(b) * heads; }
};

// Operands of a packed tensor x (B', L, C): columns [offset, offset + E) of every token; a batch
// of one is broadcast (batch stride 0).
template <class T>
Operand<const T> operand(const torch::Tensor& x, int64_t offset) {
  return {x.data_ptr<T>() + offset, x.size(0) == 1 ? 0 : x.size(1) * x.size(2), x.size(2)};
}

// exp in place over a block: float through the vector exp (kernels/vector_exp.h), double through
// the C library's.
void exp_block(float* x, int64_t n) { exp_inplace(x, n); }
void exp_block(double* x, int64_t n) {
  for (int64_t i = 0; i < n; ++i) x[i] = std::exp(x[i]);
}

// Softmax of each of the `items` x lq rows of s (lk scores each) in place, after adding the
// additive (lq, lk) mask when given: the steps of ATen's CPU softmax (max, exp of the difference,
// sum, multiply by its reciprocal) in the probabilities' own memory (no scores scratch), the
// exponentials of the whole block in one pass. Measured at the demo preset's shape (256 x 17 x 17,
// one core): with scalar expf as fast as at::_softmax_out (~0.5 ms; exp bounds both), hence the
// vector exp for float; the backward loop below takes half the time of the four tensor ops it
// replaces (~0.06 against ~0.11 ms).
template <class T>
void softmax_rows(T* s, const T* mask, int64_t items, int64_t lq, int64_t lk) {
  const int64_t rows = items * lq;
  for (int64_t q = 0; q < rows; ++q) {
    T* row = s + q * lk;
    if (mask) {
      const T* m = mask + (q % lq) * lk;
      for (int64_t j = 0; j < lk; ++j) row[j] += m[j];
    }
    const T max = row_max(row, lk);
    for (int64_t j = 0; j < lk; ++j) row[j] -= max;
  }
  exp_block(s, rows * lk);
  for (int64_t q = 0; q < rows; ++q) {
    T* row = s + q * lk;
    const T inv = T(1) / row_sum(row, lk);
    for (int64_t j = 0; j < lk; ++j) row[j] *= inv;
  }
}

// Softmax backward of each row in place: dp <- p * (dp - sum(dp * p)) (the scale is applied by
// the products that follow).
template <class T>
void softmax_backward_rows(T* dp, const T* p, int64_t rows, int64_t lk) {
  for (int64_t r = 0; r < rows; ++r) {
    T* d = dp + r * lk;
    const T* pr = p + r * lk;
    const T dot = row_dot(d, pr, lk);
    for (int64_t j = 0; j < lk; ++j) d[j] = (d[j] - dot) * pr[j];
  }
}

// The float items in AVX-512 registers (CpuVectorForm::Avx512), where a head has at most 64
// floats and a ray at most 64 queries and 64 keys: one (ray, head) at a time, K (or V) transposed
// once into a small buffer, each row of scores (up to four vectors) accumulated in registers,
// masked, exponentiated (Sleef) and normalised there, and written once as the probabilities the
// backward keeps; the products by a row of probabilities or gradients (P V, P^T dO, dS K, dS^T Q)
// through small_gemm. The same sums as the loops above in another order: float rounding apart,
// the same values.
constexpr int64_t kItemMaxTokens = 64, kItemMaxVectors = 4;

bool vector_items_fit(int64_t dh, int64_t lq, int64_t lk) {
  return dh >= 1 && dh <= kItemMaxVectors * kLanes && lq >= 1 && lq <= kItemMaxTokens && lk >= 1 &&
         lk <= kItemMaxTokens;
}

// Whether `form` selects the vector items for tensors of `type` on this CPU and build.
bool vector_items_available(CpuVectorForm form, c10::ScalarType type) {
#ifdef ABLENERF_ATTENTION_ITEMS_AVX512
  return form == CpuVectorForm::Avx512 && type == torch::kFloat && cpu_has_avx512();
#else
  (void)form;
  (void)type;
  return false;
#endif
}

#ifdef ABLENERF_ATTENTION_ITEMS_AVX512
namespace attention_items {

// One item's sizes: lq x lk scores in rows of nk vectors (ldt = 16 nk floats, the last vector's
// `last` lanes valid), heads of dh floats.
struct Shape {
  int64_t lq, lk, dh, nk, ldt;
  __mmask16 last;
};

Shape shape_of(int64_t lq, int64_t lk, int64_t dh) {
  const int64_t nk = (lk + kLanes - 1) / kLanes, rem = lk - (nk - 1) * kLanes;
  return {lq, lk, dh, nk, nk * kLanes, static_cast<__mmask16>((1u << rem) - 1u)};
}

ABLENERF_ALWAYS_INLINE __mmask16 lanes_of(const Shape& s, int v) { return v == s.nk - 1 ? s.last : 0xFFFF; }

// t (dh x ldt) = x^T, x the lk rows of one head (row stride `row`); the padding columns keep
// whatever they held (their scores are masked out).
ABLENERF_ALWAYS_INLINE void transpose_head(const float* x, int64_t row, const Shape& s, float* t) {
  for (int64_t j = 0; j < s.lk; ++j)
    for (int64_t d = 0; d < s.dh; ++d) t[d * s.ldt + j] = x[j * row + d];
}

// acc[r] = row r of A (dh floats at a + r * lda) times t (dh x ldt): R score rows of NK vectors.
template <int R, int NK>
ABLENERF_TARGET_AVX512 ABLENERF_ALWAYS_INLINE void score_rows(const float* a, int64_t lda, const Shape& s,
                                                              const float* t, __m512 (&acc)[R][NK]) {
  for (int r = 0; r < R; ++r)
    for (int v = 0; v < NK; ++v) acc[r][v] = _mm512_setzero_ps();
  for (int64_t d = 0; d < s.dh; ++d) {
    __m512 tv[NK];
    for (int v = 0; v < NK; ++v) tv[v] = _mm512_load_ps(t + d * s.ldt + v * kLanes);
    for (int r = 0; r < R; ++r) {
      const __m512 x = _mm512_set1_ps(a[r * lda + d]);
      for (int v = 0; v < NK; ++v) acc[r][v] = _mm512_fmadd_ps(x, tv[v], acc[r][v]);
    }
  }
}

// R rows of probabilities from their scores: scale, mask (additive, (lq, lk) from row i0), softmax,
// written to p (row stride lk).
template <int R, int NK>
ABLENERF_TARGET_AVX512 ABLENERF_ALWAYS_INLINE void softmax_rows(__m512 (&acc)[R][NK], const Shape& s, float scale,
                                                                const float* mask, float* p) {
  const __m512 sc = _mm512_set1_ps(scale), minus_inf = _mm512_set1_ps(-std::numeric_limits<float>::infinity());
  for (int r = 0; r < R; ++r) {
    __m512 mx = minus_inf;
    for (int v = 0; v < NK; ++v) {
      const __mmask16 k = lanes_of(s, v);
      __m512 x = _mm512_mul_ps(acc[r][v], sc);
      if (mask) x = _mm512_add_ps(x, _mm512_maskz_loadu_ps(k, mask + r * s.lk + v * kLanes));
      acc[r][v] = _mm512_mask_blend_ps(k, minus_inf, x);
      mx = _mm512_max_ps(mx, acc[r][v]);
    }
    const __m512 top = _mm512_set1_ps(_mm512_reduce_max_ps(mx));
    __m512 sum = _mm512_setzero_ps();
    for (int v = 0; v < NK; ++v) {
      acc[r][v] = Sleef_expf16_u10avx512f(_mm512_sub_ps(acc[r][v], top));
      sum = _mm512_add_ps(sum, acc[r][v]);
    }
    const __m512 inv = _mm512_set1_ps(1.0f / _mm512_reduce_add_ps(sum));
    for (int v = 0; v < NK; ++v)
      _mm512_mask_storeu_ps(p + r * s.lk + v * kLanes, lanes_of(s, v), _mm512_mul_ps(acc[r][v], inv));
  }
}

// R rows of the scores' gradient dS = P * (dP - rowsum(dP * P)) from dP in acc and P (row stride
// lk), written to ds (row stride lk).
template <int R, int NK>
ABLENERF_TARGET_AVX512 ABLENERF_ALWAYS_INLINE void softmax_backward_rows(__m512 (&acc)[R][NK], const Shape& s,
                                                                         const float* p, float* ds) {
  for (int r = 0; r < R; ++r) {
    __m512 pv[NK], dot = _mm512_setzero_ps();
    for (int v = 0; v < NK; ++v) {
      pv[v] = _mm512_maskz_loadu_ps(lanes_of(s, v), p + r * s.lk + v * kLanes);
      dot = _mm512_fmadd_ps(acc[r][v], pv[v], dot);
    }
    const __m512 total = _mm512_set1_ps(_mm512_reduce_add_ps(dot));
    for (int v = 0; v < NK; ++v)
      _mm512_mask_storeu_ps(ds + r * s.lk + v * kLanes, lanes_of(s, v),
                            _mm512_mul_ps(_mm512_sub_ps(acc[r][v], total), pv[v]));
  }
}

// The probabilities of rows [i, i + R) of one item.
template <int R, int NK>
ABLENERF_TARGET_AVX512 ABLENERF_ALWAYS_INLINE void probability_rows(const float* q, int64_t q_row, const Shape& s,
                                                                    const float* kt, float scale, const float* mask,
                                                                    float* p) {
  __m512 acc[R][NK];
  score_rows<R, NK>(q, q_row, s, kt, acc);
  softmax_rows<R, NK>(acc, s, scale, mask, p);
}

// The scores' gradient of rows [i, i + R) of one item; `row0`, when given, is a gradient on the
// first of these rows' probabilities (added to dP before the softmax's backward).
template <int R, int NK>
ABLENERF_TARGET_AVX512 ABLENERF_ALWAYS_INLINE void score_gradient_rows(const float* go, int64_t go_row, const Shape& s,
                                                                       const float* vt, const float* p, float* ds,
                                                                       const float* row0) {
  __m512 acc[R][NK];
  score_rows<R, NK>(go, go_row, s, vt, acc);
  if (row0)
    for (int v = 0; v < NK; ++v)
      acc[0][v] = _mm512_add_ps(acc[0][v], _mm512_maskz_loadu_ps(lanes_of(s, v), row0 + v * kLanes));
  softmax_backward_rows<R, NK>(acc, s, p, ds);
}

// Forward of items [lo, hi): probabilities into p (hi - lo planes of lq x lk), results into out.
template <int NK>
ABLENERF_TARGET_AVX512 void forward_items(const Problem<float>& pr, int64_t lo, int64_t hi, float* p,
                                          const Operand<float>& out) {
  const Shape s = shape_of(pr.lq, pr.lk, pr.dh);
  alignas(64) float kt[kItemMaxVectors * kLanes * kItemMaxTokens] = {};
  const float* mask = pr.mask.defined() ? pr.mask.data_ptr<float>() : nullptr;
  const float scale = static_cast<float>(pr.scale);
  for (int64_t it = lo; it < hi; ++it) {
    const int64_t b = it / pr.heads, h = it % pr.heads;
    float* pp = p + (it - lo) * s.lq * s.lk;
    const float* q = pr.q.at(b, h, s.dh);
    transpose_head(pr.k.at(b, h, s.dh), pr.k.row, s, kt);
    int64_t i = 0;
    for (; i + 4 <= s.lq; i += 4)
      probability_rows<4, NK>(q + i * pr.q.row, pr.q.row, s, kt, scale, mask ? mask + i * s.lk : nullptr,
                              pp + i * s.lk);
    for (; i < s.lq; ++i)
      probability_rows<1, NK>(q + i * pr.q.row, pr.q.row, s, kt, scale, mask ? mask + i * s.lk : nullptr,
                              pp + i * s.lk);
    small_gemm(false, s.lq, s.dh, s.lk, 1.0f, pp, s.lk, pr.v.at(b, h, s.dh), pr.v.row, out.at(b, h, s.dh), out.row);
  }
}

// Gradients of items [lo, hi), as backward_items above.
template <int NK>
ABLENERF_TARGET_AVX512 void backward_items(const Problem<float>& pr, int64_t lo, int64_t hi, const float* p,
                                           const Operand<const float>& go, const float* g_row0,
                                           const Operand<float>& dq, const Operand<float>& dk,
                                           const Operand<float>& dv) {
  const Shape s = shape_of(pr.lq, pr.lk, pr.dh);
  alignas(64) float vt[kItemMaxVectors * kLanes * kItemMaxTokens] = {};
  float ds[kItemMaxTokens * kItemMaxTokens];
  const float scale = static_cast<float>(pr.scale);
  for (int64_t it = lo; it < hi; ++it) {
    const int64_t b = it / pr.heads, h = it % pr.heads;
    const float* pp = p + (it - lo) * s.lq * s.lk;
    const float* g = go.at(b, h, s.dh);
    // dV = P^T dO; dS from dP = dO V^T; dQ = s dS K; dK = s dS^T Q.
    small_gemm(true, s.lk, s.dh, s.lq, 1.0f, pp, s.lk, g, go.row, dv.at(b, h, s.dh), dv.row);
    transpose_head(pr.v.at(b, h, s.dh), pr.v.row, s, vt);
    const float* row0 = g_row0 ? g_row0 + it * s.lk : nullptr;  // on row 0 only, the first block's first row
    int64_t i = 0;
    for (; i + 4 <= s.lq; i += 4)
      score_gradient_rows<4, NK>(g + i * go.row, go.row, s, vt, pp + i * s.lk, ds + i * s.lk, i == 0 ? row0 : nullptr);
    for (; i < s.lq; ++i)
      score_gradient_rows<1, NK>(g + i * go.row, go.row, s, vt, pp + i * s.lk, ds + i * s.lk, i == 0 ? row0 : nullptr);
    small_gemm(false, s.lq, s.dh, s.lk, scale, ds, s.lk, pr.k.at(b, h, s.dh), pr.k.row, dq.at(b, h, s.dh), dq.row);
    small_gemm(true, s.lk, s.dh, s.lq, scale, ds, s.lk, pr.q.at(b, h, s.dh), pr.q.row, dk.at(b, h, s.dh), dk.row);
  }
}

// The instantiation for the problem's score vectors (nk, 1 to 4).
template <class F>
void dispatch(const Problem<float>& pr, F&& f) {
  switch ((pr.lk + kLanes - 1) / kLanes) {
    case 1: return f(std::integral_constant<int, 1>());
    case 2: return f(std::integral_constant<int, 2>());
    case 3: return f(std::integral_constant<int, 3>());
    case 4: return f(std::integral_constant<int, 4>());
    default: TORCH_CHECK(false, "packed attention: no vector form for ", pr.lk, " keys");
  }
}

}  // namespace attention_items

// Rays in lanes: sixteen rays of one head side by side in each AVX-512 vector, every (query, key,
// feature) of the item a vector over those rays. Why: at the capture preset (heads of 16 floats,
// 17 tokens) the items above spend most of their time on what is not arithmetic: K and V
// transposed element by element, a row's 17 scores in two vectors (the second with one lane in
// use), and a horizontal max, sum and division per row; here scores, softmax and products are
// plain vector arithmetic with every lane in use, the row statistics need no horizontal
// reduction, and a key the additive mask blocks (-inf, the AB transformer's farther samples) is
// skipped outright, its probability 0 as the reference's exp(-inf) gives. Each token's rows of
// the sixteen rays are loaded whole and transposed in registers (16 x 16 at a time), and the
// results transposed back the same way. One thread, 128 rays of 17 tokens, two heads of 16:
// forward 233-253 us -> 58-82, forward and backward 562-595 -> 272-320 (docs/benchmarks/history.md,
// "Rays in lanes"). Float only; heads of 16 or 24 floats (the capture and demo presets), at most
// 32 queries and keys, at least one full group of rays. The same formulas in the same order per
// element as softmax_rows above (scale, mask, max, exp of the difference, sum, times its
// reciprocal); the products' sums in another order.
namespace ray_lanes {

constexpr int64_t kMaxTokens = 32;

bool fit(int64_t b, int64_t dh, int64_t lq, int64_t lk) {
  return (dh == 16 || dh == 24) && b >= kLanes && lq >= 1 && lq <= kMaxTokens && lk >= 1 && lk <= kMaxTokens;
}

// The group's rays and their lanes: ray r0 + lane, `valid` the lanes below the batch's end.
struct Group {
  int64_t r0;
  __mmask16 valid;
};

ABLENERF_TARGET_AVX512 ABLENERF_ALWAYS_INLINE __m512i strides(int64_t stride) {
  return _mm512_mullo_epi32(_mm512_set_epi32(15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0),
                            _mm512_set1_epi32(static_cast<int32_t>(stride)));
}

// r[k] = column k of the 16 x 16 matrix whose rows r held (in place): three rounds of shuffles.
ABLENERF_TARGET_AVX512 ABLENERF_ALWAYS_INLINE void transpose16(__m512 (&r)[kLanes]) {
  __m512 t[kLanes];
  for (int i = 0; i < 8; ++i) {
    t[2 * i] = _mm512_unpacklo_ps(r[2 * i], r[2 * i + 1]);
    t[2 * i + 1] = _mm512_unpackhi_ps(r[2 * i], r[2 * i + 1]);
  }
  for (int i = 0; i < 4; ++i) {
    r[4 * i] = _mm512_castpd_ps(_mm512_unpacklo_pd(_mm512_castps_pd(t[4 * i]), _mm512_castps_pd(t[4 * i + 2])));
    r[4 * i + 1] = _mm512_castpd_ps(_mm512_unpackhi_pd(_mm512_castps_pd(t[4 * i]), _mm512_castps_pd(t[4 * i + 2])));
    r[4 * i + 2] = _mm512_castpd_ps(_mm512_unpacklo_pd(_mm512_castps_pd(t[4 * i + 1]), _mm512_castps_pd(t[4 * i + 3])));
    r[4 * i + 3] = _mm512_castpd_ps(_mm512_unpackhi_pd(_mm512_castps_pd(t[4 * i + 1]), _mm512_castps_pd(t[4 * i + 3])));
  }
  for (int i = 0; i < 4; ++i) {
    t[i] = _mm512_shuffle_f32x4(r[i], r[4 + i], 0x88);
    t[4 + i] = _mm512_shuffle_f32x4(r[i], r[4 + i], 0xdd);
    t[8 + i] = _mm512_shuffle_f32x4(r[8 + i], r[12 + i], 0x88);
    t[12 + i] = _mm512_shuffle_f32x4(r[8 + i], r[12 + i], 0xdd);
  }
  for (int i = 0; i < 4; ++i) {
    r[i] = _mm512_shuffle_f32x4(t[i], t[8 + i], 0x88);
    r[8 + i] = _mm512_shuffle_f32x4(t[i], t[8 + i], 0xdd);
    r[4 + i] = _mm512_shuffle_f32x4(t[4 + i], t[12 + i], 0x88);
    r[12 + i] = _mm512_shuffle_f32x4(t[4 + i], t[12 + i], 0xdd);
  }
}

// The valid lanes' count.
ABLENERF_ALWAYS_INLINE int64_t lane_count(const Group& g) { return __builtin_popcount(g.valid); }

// The columns [d0, d0 + 16) of a head of `head` floats that exist, as a lane mask.
ABLENERF_ALWAYS_INLINE __mmask16 chunk_columns(int64_t head, int64_t d0) {
  return head - d0 >= kLanes ? 0xFFFF : static_cast<__mmask16>((1u << (head - d0)) - 1u);
}

// t[(i * dh + d) * 16 + lane] = x(ray r0 + lane)[i][d] for n tokens (0 in invalid lanes): each
// token's rows of the sixteen rays loaded whole, 16 features at a time, and transposed.
template <int64_t kHead, class T>
ABLENERF_TARGET_AVX512 ABLENERF_ALWAYS_INLINE void gather_tokens(const Operand<T>& x, const Group& g, int64_t h,
                                                                 int64_t n, float* t) {
  const int64_t rays = lane_count(g);
  for (int64_t i = 0; i < n; ++i)
    for (int64_t d0 = 0; d0 < kHead; d0 += kLanes) {
      const __mmask16 cols = chunk_columns(kHead, d0);
      __m512 r[kLanes];
      for (int64_t l = 0; l < kLanes; ++l)
        r[l] = l < rays ? _mm512_maskz_loadu_ps(cols, x.at(g.r0 + l, h, kHead) + i * x.row + d0) : _mm512_setzero_ps();
      transpose16(r);
      for (int64_t d = d0; d < kHead && d < d0 + kLanes; ++d) _mm512_store_ps(t + (i * kHead + d) * kLanes, r[d - d0]);
    }
}

// x(ray r0 + lane)[i][d] = scale * t[(i * dh + d) * 16 + lane] for the valid lanes.
template <int64_t kHead>
ABLENERF_TARGET_AVX512 ABLENERF_ALWAYS_INLINE void scatter_tokens(const float* t, float scale, const Group& g,
                                                                  int64_t h, int64_t n, const Operand<float>& x) {
  const int64_t rays = lane_count(g);
  const __m512 sc = _mm512_set1_ps(scale);
  for (int64_t i = 0; i < n; ++i)
    for (int64_t d0 = 0; d0 < kHead; d0 += kLanes) {
      const __mmask16 cols = chunk_columns(kHead, d0);
      __m512 r[kLanes];
      for (int64_t d = 0; d < kLanes; ++d)
        r[d] =
            d0 + d < kHead ? _mm512_mul_ps(_mm512_load_ps(t + (i * kHead + d0 + d) * kLanes), sc) : _mm512_setzero_ps();
      transpose16(r);
      for (int64_t l = 0; l < rays; ++l) _mm512_mask_storeu_ps(x.at(g.r0 + l, h, kHead) + i * x.row + d0, cols, r[l]);
    }
}

// Whether the additive mask blocks (i, j) outright.
ABLENERF_ALWAYS_INLINE bool blocked(const float* mask, int64_t lk, int64_t i, int64_t j) {
  return mask != nullptr && mask[i * lk + j] == -std::numeric_limits<float>::infinity();
}

// sum over d of x[d] t[d] (t: one token's kHead vectors), in two chains of sums.
template <int64_t kHead>
ABLENERF_TARGET_AVX512 ABLENERF_ALWAYS_INLINE __m512 token_dot(const __m512 (&x)[kHead], const float* t) {
  __m512 a0 = _mm512_mul_ps(x[0], _mm512_load_ps(t)), a1 = _mm512_mul_ps(x[1], _mm512_load_ps(t + kLanes));
  for (int64_t d = 2; d < kHead; d += 2) {
    a0 = _mm512_fmadd_ps(x[d], _mm512_load_ps(t + d * kLanes), a0);
    a1 = _mm512_fmadd_ps(x[d + 1], _mm512_load_ps(t + (d + 1) * kLanes), a1);
  }
  return _mm512_add_ps(a0, a1);
}

// One (group, head): probabilities into p (lq x lk vectors), the output into out, row 0 of the
// probabilities into row0 when given ((B, H, lk)).
template <int64_t kHead>
ABLENERF_TARGET_AVX512 void forward_unit(const Problem<float>& pr, const Group& g, int64_t h, float* scratch, float* p,
                                         const Operand<float>& out, float* row0) {
  const int64_t lq = pr.lq, lk = pr.lk;
  float* qt = scratch;
  float* kt = qt + lq * kHead * kLanes;
  float* vt = kt + lk * kHead * kLanes;
  float* ot = vt + lk * kHead * kLanes;
  gather_tokens<kHead>(pr.q, g, h, lq, qt);
  gather_tokens<kHead>(pr.k, g, h, lk, kt);
  gather_tokens<kHead>(pr.v, g, h, lk, vt);
  const float* mask = pr.mask.defined() ? pr.mask.data_ptr<float>() : nullptr;
  const __m512 sc = _mm512_set1_ps(static_cast<float>(pr.scale));
  const __m512 minus_inf = _mm512_set1_ps(-std::numeric_limits<float>::infinity());
  for (int64_t i = 0; i < lq; ++i) {
    __m512 q[kHead];
    for (int64_t d = 0; d < kHead; ++d) q[d] = _mm512_load_ps(qt + (i * kHead + d) * kLanes);
    float* prow = p + i * lk * kLanes;
    __m512 mx = minus_inf;
    for (int64_t j = 0; j < lk; ++j) {
      if (blocked(mask, lk, i, j)) continue;
      __m512 s = _mm512_mul_ps(token_dot<kHead>(q, kt + j * kHead * kLanes), sc);
      if (mask) s = _mm512_add_ps(s, _mm512_set1_ps(mask[i * lk + j]));
      _mm512_store_ps(prow + j * kLanes, s);
      mx = _mm512_max_ps(mx, s);
    }
    __m512 sum = _mm512_setzero_ps();
    for (int64_t j = 0; j < lk; ++j) {
      if (blocked(mask, lk, i, j)) continue;
      const __m512 e = Sleef_expf16_u10avx512f(_mm512_sub_ps(_mm512_load_ps(prow + j * kLanes), mx));
      _mm512_store_ps(prow + j * kLanes, e);
      sum = _mm512_add_ps(sum, e);
    }
    const __m512 inv = _mm512_div_ps(_mm512_set1_ps(1.0f), sum);
    __m512 o[kHead];
    for (int64_t d = 0; d < kHead; ++d) o[d] = _mm512_setzero_ps();
    for (int64_t j = 0; j < lk; ++j) {
      if (blocked(mask, lk, i, j)) {
        _mm512_store_ps(prow + j * kLanes, _mm512_setzero_ps());
        continue;
      }
      const __m512 pj = _mm512_mul_ps(_mm512_load_ps(prow + j * kLanes), inv);
      _mm512_store_ps(prow + j * kLanes, pj);
      const float* vj = vt + j * kHead * kLanes;
      for (int64_t d = 0; d < kHead; ++d) o[d] = _mm512_fmadd_ps(pj, _mm512_load_ps(vj + d * kLanes), o[d]);
    }
    for (int64_t d = 0; d < kHead; ++d) _mm512_store_ps(ot + (i * kHead + d) * kLanes, o[d]);
  }
  scatter_tokens<kHead>(ot, 1.0f, g, h, lq, out);
  if (row0) {
    const __m512i idx = strides(pr.heads * lk);
    for (int64_t j = 0; j < lk; ++j)
      _mm512_mask_i32scatter_ps(row0 + (g.r0 * pr.heads + h) * lk + j, g.valid, idx, _mm512_load_ps(p + j * kLanes), 4);
  }
}

// Key j's row of A^T T into out: out[j][d] = sum over the queries i that see key j of a[i][j] t[i][d]
// (a: lq x lk vectors, t and out: tokens of kHead vectors), the sums in registers.
template <int64_t kHead>
ABLENERF_TARGET_AVX512 ABLENERF_ALWAYS_INLINE void key_column(const float* a, const float* t, const float* mask,
                                                              int64_t lq, int64_t lk, int64_t j, float* out) {
  __m512 acc[kHead];
  for (int64_t d = 0; d < kHead; ++d) acc[d] = _mm512_setzero_ps();
  for (int64_t i = 0; i < lq; ++i) {
    if (blocked(mask, lk, i, j)) continue;
    const __m512 aij = _mm512_load_ps(a + (i * lk + j) * kLanes);
    const float* ti = t + i * kHead * kLanes;
    for (int64_t d = 0; d < kHead; ++d) acc[d] = _mm512_fmadd_ps(aij, _mm512_load_ps(ti + d * kLanes), acc[d]);
  }
  for (int64_t d = 0; d < kHead; ++d) _mm512_store_ps(out + (j * kHead + d) * kLanes, acc[d]);
}

// One (group, head)'s gradients, every element of dq, dk and dv written. Query by query: dP = dO
// V^T (+ the row-0 gradient on row 0), dS = P * (dP - rowsum(dP * P)) kept whole, dQ = s dS K in
// registers; then key by key, in registers over the queries: dV = P^T dO, dK = s dS^T Q.
template <int64_t kHead>
ABLENERF_TARGET_AVX512 void backward_unit(const Problem<float>& pr, const Group& g, int64_t h, float* scratch,
                                          const float* p, const Operand<const float>& go, const float* g_row0,
                                          const Operand<float>& dq, const Operand<float>& dk,
                                          const Operand<float>& dv) {
  const int64_t lq = pr.lq, lk = pr.lk, qs = lq * kHead * kLanes, ks = lk * kHead * kLanes;
  float* qt = scratch;
  float* kt = qt + qs;
  float* vt = kt + ks;
  float* gt = vt + ks;
  float* dqt = gt + qs;
  float* dkt = dqt + qs;
  float* dvt = dkt + ks;
  float* ds = dvt + ks;  // lq x lk vectors
  gather_tokens<kHead>(pr.q, g, h, lq, qt);
  gather_tokens<kHead>(pr.k, g, h, lk, kt);
  gather_tokens<kHead>(pr.v, g, h, lk, vt);
  gather_tokens<kHead>(go, g, h, lq, gt);
  const float* mask = pr.mask.defined() ? pr.mask.data_ptr<float>() : nullptr;
  for (int64_t i = 0; i < lq; ++i) {
    const float* prow = p + i * lk * kLanes;
    float* dsrow = ds + i * lk * kLanes;
    __m512 dot = _mm512_setzero_ps();
    {
      __m512 gi[kHead];
      for (int64_t d = 0; d < kHead; ++d) gi[d] = _mm512_load_ps(gt + (i * kHead + d) * kLanes);
      for (int64_t j = 0; j < lk; ++j) {
        if (blocked(mask, lk, i, j)) continue;
        __m512 dp = token_dot<kHead>(gi, vt + j * kHead * kLanes);
        if (i == 0 && g_row0)
          dp = _mm512_add_ps(dp, _mm512_mask_i32gather_ps(_mm512_setzero_ps(), g.valid, strides(pr.heads * lk),
                                                          g_row0 + (g.r0 * pr.heads + h) * lk + j, 4));
        _mm512_store_ps(dsrow + j * kLanes, dp);
        dot = _mm512_fmadd_ps(dp, _mm512_load_ps(prow + j * kLanes), dot);
      }
    }
    __m512 dqi[kHead];
    for (int64_t d = 0; d < kHead; ++d) dqi[d] = _mm512_setzero_ps();
    for (int64_t j = 0; j < lk; ++j) {
      if (blocked(mask, lk, i, j)) {
        _mm512_store_ps(dsrow + j * kLanes, _mm512_setzero_ps());
        continue;
      }
      const __m512 dsj =
          _mm512_mul_ps(_mm512_load_ps(prow + j * kLanes), _mm512_sub_ps(_mm512_load_ps(dsrow + j * kLanes), dot));
      const float* kj = kt + j * kHead * kLanes;
      for (int64_t d = 0; d < kHead; ++d) dqi[d] = _mm512_fmadd_ps(dsj, _mm512_load_ps(kj + d * kLanes), dqi[d]);
      _mm512_store_ps(dsrow + j * kLanes, dsj);
    }
    for (int64_t d = 0; d < kHead; ++d) _mm512_store_ps(dqt + (i * kHead + d) * kLanes, dqi[d]);
  }
  for (int64_t j = 0; j < lk; ++j) {
    key_column<kHead>(p, gt, mask, lq, lk, j, dvt);   // dV = P^T dO
    key_column<kHead>(ds, qt, mask, lq, lk, j, dkt);  // dK / s = dS^T Q
  }
  const float scale = static_cast<float>(pr.scale);
  scatter_tokens<kHead>(dqt, scale, g, h, lq, dq);
  scatter_tokens<kHead>(dkt, scale, g, h, lk, dk);
  scatter_tokens<kHead>(dvt, 1.0f, g, h, lk, dv);
}

// Floats of one unit's scratch (forward: Q, K, V, O; backward: Q, K, V, dO, dQ, dK, dV, dS).
int64_t scratch_floats(const Problem<float>& pr) {
  return (3 * pr.lq + 4 * pr.lk) * pr.dh * kLanes + pr.lq * pr.lk * kLanes;
}

// f(std::integral_constant<int64_t, dh>) for the head widths fit() takes.
template <class F>
void dispatch(const Problem<float>& pr, F&& f) {
  if (pr.dh == 16) return f(std::integral_constant<int64_t, 16>());
  TORCH_CHECK(pr.dh == 24, "packed attention: no ray-lane form for heads of ", pr.dh);
  f(std::integral_constant<int64_t, 24>());
}

Group group_of(const Problem<float>& pr, int64_t unit) {
  const int64_t r0 = unit / pr.heads * kLanes, n = std::min<int64_t>(kLanes, pr.b - r0);
  return {r0, static_cast<__mmask16>((1u << n) - 1u)};
}

}  // namespace ray_lanes
#endif

// Whether the ray-lane form takes a problem of these sizes in `form` for tensors of `type`.
bool lanes_available(CpuVectorForm form, c10::ScalarType type, int64_t b, int64_t dh, int64_t lq, int64_t lk) {
#ifdef ABLENERF_ATTENTION_ITEMS_AVX512
  return vector_items_available(form, type) && ray_lanes::fit(b, dh, lq, lk);
#else
  (void)form, (void)type, (void)b, (void)dh, (void)lq, (void)lk;
  return false;
#endif
}

// The forward and backward of every (group of sixteen rays, head) in the ray-lane form.
template <class T>
void forward_lanes(const Problem<T>&, T*, const Operand<T>&, T*) {
  TORCH_CHECK(false, "packed attention: the ray-lane form is float only");
}
template <class T>
void backward_lanes(const Problem<T>&, const T*, const Operand<const T>&, const T*, const Operand<T>&,
                    const Operand<T>&, const Operand<T>&) {
  TORCH_CHECK(false, "packed attention: the ray-lane form is float only");
}
#ifdef ABLENERF_ATTENTION_ITEMS_AVX512
// Units of (group, head) per thread below which a second thread costs more than it saves.
constexpr int64_t kMinUnitsPerThread = 2;

// keep: the planes() probabilities saved for backward, or null (then each thread's own scratch).
template <>
void forward_lanes<float>(const Problem<float>& pr, float* keep, const Operand<float>& out, float* row0) {
  const int64_t units = pr.lane_units(), plane = pr.lq * pr.lk * kLanes;
  parallel_slices(units, cpu_workers(units, kMinUnitsPerThread), [&](int64_t, int64_t lo, int64_t hi) {
    thread_local AlignedFloats scratch;
    scratch.resize(static_cast<size_t>(ray_lanes::scratch_floats(pr) + (keep ? 0 : plane)));
    float* own = scratch.data() + ray_lanes::scratch_floats(pr);
    ray_lanes::dispatch(pr, [&](auto dh) {
      for (int64_t u = lo; u < hi; ++u)
        ray_lanes::forward_unit<decltype(dh)::value>(pr, ray_lanes::group_of(pr, u), u % pr.heads, scratch.data(),
                                                     keep ? keep + u * plane : own, out, row0);
    });
  });
}
template <>
void backward_lanes<float>(const Problem<float>& pr, const float* p, const Operand<const float>& go,
                           const float* g_row0, const Operand<float>& dq, const Operand<float>& dk,
                           const Operand<float>& dv) {
  const int64_t units = pr.lane_units(), plane = pr.lq * pr.lk * kLanes;
  parallel_slices(units, cpu_workers(units, kMinUnitsPerThread), [&](int64_t, int64_t lo, int64_t hi) {
    thread_local AlignedFloats scratch;
    scratch.resize(static_cast<size_t>(ray_lanes::scratch_floats(pr)));
    ray_lanes::dispatch(pr, [&](auto dh) {
      for (int64_t u = lo; u < hi; ++u)
        ray_lanes::backward_unit<decltype(dh)::value>(pr, ray_lanes::group_of(pr, u), u % pr.heads, scratch.data(),
                                                      p + u * plane, go, g_row0, dq, dk, dv);
    });
  });
}
#endif

// The items [lo, hi) in the vector form when the problem chose it (float only): true when done.
template <class T>
bool forward_vector_items(const Problem<T>&, int64_t, int64_t, T*, const Operand<T>&) {
  return false;
}
template <class T>
bool backward_vector_items(const Problem<T>&, int64_t, int64_t, const T*, const Operand<const T>&, const T*,
                           const Operand<T>&, const Operand<T>&, const Operand<T>&) {
  return false;
}
#ifdef ABLENERF_ATTENTION_ITEMS_AVX512
bool forward_vector_items(const Problem<float>& pr, int64_t lo, int64_t hi, float* p, const Operand<float>& out) {
  if (!pr.vector_items) return false;
  attention_items::dispatch(pr,
                            [&](auto nk) { attention_items::forward_items<decltype(nk)::value>(pr, lo, hi, p, out); });
  return true;
}
bool backward_vector_items(const Problem<float>& pr, int64_t lo, int64_t hi, const float* p,
                           const Operand<const float>& go, const float* g_row0, const Operand<float>& dq,
                           const Operand<float>& dk, const Operand<float>& dv) {
  if (!pr.vector_items) return false;
  attention_items::dispatch(pr, [&](auto nk) {
    attention_items::backward_items<decltype(nk)::value>(pr, lo, hi, p, go, g_row0, dq, dk, dv);
  });
  return true;
}
#endif

// Probabilities of items [lo, hi) into p (hi - lo, lq, lk) and their weighted values into out.
template <class T>
void forward_items(const Problem<T>& pr, int64_t lo, int64_t hi, torch::Tensor p, const Operand<T>& out) {
  T* s = p.data_ptr<T>();
  const int64_t plane = pr.lq * pr.lk;
  std::vector<T> scratch;
  for (int64_t it = lo; it < hi; ++it) {
    const int64_t b = it / pr.heads, h = it % pr.heads;
    product(false, true, pr.lq, pr.lk, pr.dh, T(pr.scale), pr.q.at(b, h, pr.dh), pr.q.row, pr.k.at(b, h, pr.dh),
            pr.k.row, s + (it - lo) * plane, pr.lk, scratch);
  }
  softmax_rows(s, pr.mask.defined() ? pr.mask.template data_ptr<T>() : nullptr, hi - lo, pr.lq, pr.lk);
  const T* pp = p.data_ptr<T>();
  for (int64_t it = lo; it < hi; ++it) {
    const int64_t b = it / pr.heads, h = it % pr.heads;
    product(false, false, pr.lq, pr.dh, pr.lk, T(1), pp + (it - lo) * plane, pr.lk, pr.v.at(b, h, pr.dh), pr.v.row,
            out.at(b, h, pr.dh), out.row, scratch);
  }
}

// The forward of every item; `keep` = the (B*H, lq, lk) probabilities to save for backward, or
// undefined when nothing will be differentiated (then each thread uses a scratch of its own);
// `row0`, when defined, the (B, H, lk) first query's probabilities, copied out of them.
template <class T>
torch::Tensor forward_all(const Problem<T>& pr, const torch::TensorOptions& options, torch::Tensor keep,
                          const torch::Tensor& row0) {
  auto out = torch::empty({pr.b, pr.lq, pr.heads * pr.dh}, options);
  const Operand<T> o{out.template data_ptr<T>(), pr.lq * pr.heads * pr.dh, pr.heads * pr.dh};
  T* row0_at = row0.defined() ? row0.template data_ptr<T>() : nullptr;
  if (pr.lanes) {
    forward_lanes(pr, keep.defined() ? keep.template data_ptr<T>() : nullptr, o, row0_at);
    return out;
  }
  const SingleThreadedBlas single;  // also when serial: OpenBLAS's pool costs more than it saves here
  parallel_slices(pr.items(), cpu_workers(pr.items(), kMinItemsPerThread), [&](int64_t, int64_t lo, int64_t hi) {
    auto p = keep.defined() ? keep.slice(0, lo, hi) : torch::empty({hi - lo, pr.lq, pr.lk}, options);
    T* pp = p.template data_ptr<T>();
    if (!forward_vector_items(pr, lo, hi, pp, o)) forward_items(pr, lo, hi, p, o);
    if (row0_at)
      for (int64_t it = lo; it < hi; ++it) std::copy_n(pp + (it - lo) * pr.lq * pr.lk, pr.lk, row0_at + it * pr.lk);
  });
  return out;
}

// Gradients of items [lo, hi): dq, dk, dv operands receive the products (every element written);
// g_row0, when given, is the (B * H, lk) gradient on each item's first row of probabilities.
template <class T>
void backward_items(const Problem<T>& pr, int64_t lo, int64_t hi, const torch::Tensor& p_all,
                    const Operand<const T>& go, const T* g_row0, const Operand<T>& dq, const Operand<T>& dk,
                    const Operand<T>& dv) {
  const auto p = p_all.slice(0, lo, hi);
  auto dp = torch::empty_like(p);
  const int64_t plane = pr.lq * pr.lk;
  const T* pp = p.data_ptr<T>();
  T* dpp = dp.data_ptr<T>();
  std::vector<T> scratch;
  for (int64_t it = lo; it < hi; ++it) {
    const int64_t b = it / pr.heads, h = it % pr.heads;
    // dP = dO V^T;  dV = P^T dO.
    product(false, true, pr.lq, pr.lk, pr.dh, T(1), go.at(b, h, pr.dh), go.row, pr.v.at(b, h, pr.dh), pr.v.row,
            dpp + (it - lo) * plane, pr.lk, scratch);
    product(true, false, pr.lk, pr.dh, pr.lq, T(1), pp + (it - lo) * plane, pr.lk, go.at(b, h, pr.dh), go.row,
            dv.at(b, h, pr.dh), dv.row, scratch);
  }
  if (g_row0)
    for (int64_t it = lo; it < hi; ++it)
      for (int64_t j = 0; j < pr.lk; ++j) dpp[(it - lo) * plane + j] += g_row0[it * pr.lk + j];
  // Softmax backward: dS = P * (dP - rowsum(dP * P)), in place; the scale multiplies dQ and dK below.
  softmax_backward_rows(dpp, pp, (hi - lo) * pr.lq, pr.lk);
  const T* dsp = dpp;
  for (int64_t it = lo; it < hi; ++it) {
    const int64_t b = it / pr.heads, h = it % pr.heads;
    // dQ = s dS K;  dK = s dS^T Q.
    product(false, false, pr.lq, pr.dh, pr.lk, T(pr.scale), dsp + (it - lo) * plane, pr.lk, pr.k.at(b, h, pr.dh),
            pr.k.row, dq.at(b, h, pr.dh), dq.row, scratch);
    product(true, false, pr.lk, pr.dh, pr.lq, T(pr.scale), dsp + (it - lo) * plane, pr.lk, pr.q.at(b, h, pr.dh),
            pr.q.row, dk.at(b, h, pr.dh), dk.row, scratch);
  }
}

// Columns of K and V in the tensor holding them: [Q | K | V] for self-attention, [K | V] otherwise.
struct KvColumns {
  int64_t k, v;
};
KvColumns kv_columns(bool self, int64_t width) { return self ? KvColumns{width, 2 * width} : KvColumns{0, width}; }

// q_src: (Bq, Lq, C) holding Q at columns [0, E); kv: (B, Lk, C') holding K and V (for
// self-attention kv is q_src).
template <class T>
Problem<T> make_problem(const torch::Tensor& q_src, const torch::Tensor& kv, bool self, int64_t heads, int64_t width,
                        const torch::Tensor& mask, double scale, CpuVectorForm form) {
  const KvColumns c = kv_columns(self, width);
  const bool vector_items =
      vector_items_available(form, q_src.scalar_type()) && vector_items_fit(width / heads, q_src.size(1), kv.size(1));
  Problem<T> pr{kv.size(0),
                heads,
                width / heads,
                q_src.size(1),
                kv.size(1),
                operand<T>(q_src, 0),
                operand<T>(kv, c.k),
                operand<T>(kv, c.v),
                mask.defined() && mask.numel() > 0 ? mask : torch::Tensor(),
                scale,
                vector_items,
                lanes_available(form, q_src.scalar_type(), kv.size(0), width / heads, q_src.size(1), kv.size(1))};
  return pr;
}

// Autograd node over the packed tensors, so that the gradient lands in the packed layout directly
// (no per-head copies, no zero-filled slices summed together). Its second output is the first
// query's probabilities (B, H, lk), filled when `with_row0` (an empty tensor otherwise): a gradient
// on them joins the softmax's backward, so a loss on the ray token's attention row costs no
// gradient of the packed tensor's size of its own.
class PackedAttentionFunction : public torch::autograd::Function<PackedAttentionFunction> {
 public:
  // kv_src empty = self-attention (K and V inside q_src).
  static torch::autograd::variable_list forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& q_src,
                                                const torch::Tensor& kv_src, const torch::Tensor& mask, int64_t heads,
                                                int64_t width, double scale, int64_t form, bool with_row0) {
    const bool self = kv_src.numel() == 0;
    const auto& kv = self ? q_src : kv_src;
    torch::Tensor p;
    auto row0 =
        with_row0 ? torch::empty({kv.size(0), heads, kv.size(1)}, q_src.options()) : torch::empty({0}, q_src.options());
    torch::Tensor out;
    AT_DISPATCH_FLOATING_TYPES(q_src.scalar_type(), "packed_attention", [&] {
      const auto pr =
          make_problem<scalar_t>(q_src, kv, self, heads, width, mask, scale, static_cast<CpuVectorForm>(form));
      p = torch::empty({pr.planes(), pr.lq, pr.lk}, q_src.options());
      out = forward_all(pr, q_src.options(), p, with_row0 ? row0 : torch::Tensor());
    });
    ctx->set_materialize_grads(false);
    ctx->save_for_backward({q_src, kv_src, mask, p});
    ctx->saved_data["heads"] = heads;
    ctx->saved_data["width"] = width;
    ctx->saved_data["scale"] = scale;
    ctx->saved_data["form"] = form;
    return {out, row0};
  }

  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                 torch::autograd::variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    const auto &q_src = saved[0], &kv_src = saved[1], &mask = saved[2], &p = saved[3];
    const int64_t heads = ctx->saved_data["heads"].toInt(), width = ctx->saved_data["width"].toInt();
    const double scale = ctx->saved_data["scale"].toDouble();
    const auto form = static_cast<CpuVectorForm>(ctx->saved_data["form"].toInt());
    const bool self = kv_src.numel() == 0;
    const auto& kv = self ? q_src : kv_src;
    const int64_t b = kv.size(0);
    const int64_t lq = q_src.size(1);
    // Undefined gradients (materialisation is off) are zeros: the output's made here, the row's skipped.
    const auto go = grads[0].defined() ? grads[0].contiguous() : torch::zeros({b, lq, width}, q_src.options());
    const auto g_row0 = grads[1].defined() && grads[1].numel() > 0 ? grads[1].contiguous() : torch::Tensor();
    // Self: one (B, L, 3E) gradient. Cross: dQ per ray (summed afterwards when the queries are
    // shared by the batch) and one (B, Lk, 2E) gradient for K and V.
    auto d_kv = torch::empty({b, kv.size(1), kv.size(2)}, kv.options());
    auto d_q = self ? d_kv : torch::empty({b, lq, width}, q_src.options());
    AT_DISPATCH_FLOATING_TYPES(q_src.scalar_type(), "packed_attention_backward", [&] {
      const auto pr = make_problem<scalar_t>(q_src, kv, self, heads, width, mask, scale, form);
      const Operand<const scalar_t> g{go.data_ptr<scalar_t>(), go.size(1) * go.size(2), go.size(2)};
      const scalar_t* gr = g_row0.defined() ? g_row0.data_ptr<scalar_t>() : nullptr;
      const auto out_operand = [](torch::Tensor& x, int64_t offset) {
        return Operand<scalar_t>{x.data_ptr<scalar_t>() + offset, x.size(1) * x.size(2), x.size(2)};
      };
      const auto dq = out_operand(d_q, 0);
      const KvColumns c = kv_columns(self, width);
      const auto dk = out_operand(d_kv, c.k), dv = out_operand(d_kv, c.v);
      if (pr.lanes) return backward_lanes(pr, p.data_ptr<scalar_t>(), g, gr, dq, dk, dv);
      const SingleThreadedBlas single;
      parallel_slices(pr.items(), cpu_workers(pr.items(), kMinItemsPerThread), [&](int64_t, int64_t lo, int64_t hi) {
        if (!backward_vector_items(pr, lo, hi, p.data_ptr<scalar_t>() + lo * pr.lq * pr.lk, g, gr, dq, dk, dv))
          backward_items(pr, lo, hi, p, g, gr, dq, dk, dv);
      });
    });
    const torch::Tensor none;
    if (self) return {d_kv, none, none, none, none, none, none, none};
    if (q_src.size(0) == 1 && b != 1) d_q = d_q.sum(0, /*keepdim=*/true);
    return {d_q, d_kv, none, none, none, none, none, none};
  }
};

PackedAttention run(const torch::Tensor& q_src, const torch::Tensor& kv_src, const torch::Tensor& mask, int64_t heads,
                    int64_t width, double scale, CpuVectorForm form, bool with_row0) {
  RECORD_FUNCTION("ablenerf::packed_attention", std::vector<c10::IValue>());
  const bool self = !kv_src.defined();
  TORCH_CHECK(width % heads == 0, "packed attention: width ", width, " is not divisible by ", heads, " heads");
  const auto q = q_src.contiguous();
  const auto kv = self ? torch::Tensor() : kv_src.contiguous();
  const auto m = mask.defined() ? mask.to(q.scalar_type()).contiguous() : torch::Tensor();
  const int64_t lk = self ? q.size(1) : kv.size(1);
  TORCH_CHECK(!m.defined() || m.numel() == 0 || (m.dim() == 2 && m.size(0) == q.size(1) && m.size(1) == lk),
              "packed attention: the mask must be (", q.size(1), ", ", lk, "), got ", m.sizes());
  const bool needs_graph = torch::GradMode::is_enabled() && (q.requires_grad() || (kv.defined() && kv.requires_grad()));
  if (needs_graph) {
    const auto outs = PackedAttentionFunction::apply(q, self ? torch::empty({0}, q.options()) : kv,
                                                     m.defined() ? m : torch::empty({0}, q.options()), heads, width,
                                                     scale, static_cast<int64_t>(form), with_row0);
    return {outs[0], with_row0 ? outs[1] : torch::Tensor()};
  }
  PackedAttention r;
  AT_DISPATCH_FLOATING_TYPES(q.scalar_type(), "packed_attention_inference", [&] {
    const auto& kvt = self ? q : kv;
    const auto pr = make_problem<scalar_t>(q, kvt, self, heads, width, m, scale, form);
    if (with_row0) r.row0 = torch::empty({pr.b, heads, lk}, q.options());
    r.out = forward_all(pr, q.options(), torch::Tensor(), r.row0);
  });
  return r;
}

}  // namespace

bool packed_attention_available(const torch::Tensor& x) {
  if (!x.device().is_cpu()) return false;
  if (x.scalar_type() == torch::kFloat) return cblas().s != nullptr;
  if (x.scalar_type() == torch::kDouble) return cblas().d != nullptr;
  return false;
}

namespace {

PackedAttention self_attention(const torch::Tensor& qkv, int64_t heads, const torch::Tensor& mask, double scale,
                               CpuVectorForm form, bool with_row0) {
  TORCH_CHECK(qkv.dim() == 3 && qkv.size(2) % 3 == 0, "packed_self_attention: expected (B, L, 3E), got ", qkv.sizes());
  return run(qkv, torch::Tensor(), mask, heads, qkv.size(2) / 3, scale, form, with_row0);
}

}  // namespace

torch::Tensor packed_self_attention(const torch::Tensor& qkv, int64_t heads, const torch::Tensor& mask, double scale,
                                    CpuVectorForm form) {
  return self_attention(qkv, heads, mask, scale, form, /*with_row0=*/false).out;
}

PackedAttention packed_self_attention_row0(const torch::Tensor& qkv, int64_t heads, const torch::Tensor& mask,
                                           double scale, CpuVectorForm form) {
  return self_attention(qkv, heads, mask, scale, form, /*with_row0=*/true);
}

torch::Tensor packed_cross_attention(const torch::Tensor& q, const torch::Tensor& kv, int64_t heads, double scale,
                                     CpuVectorForm form) {
  TORCH_CHECK(
      q.dim() == 3 && kv.dim() == 3 && kv.size(2) == 2 * q.size(2) && (q.size(0) == 1 || q.size(0) == kv.size(0)),
      "packed_cross_attention: expected q (B or 1, Lq, E) and kv (B, Lk, 2E), got ", q.sizes(), " and ", kv.sizes());
  return run(q, kv, torch::Tensor(), heads, q.size(2), scale, form, /*with_row0=*/false).out;
}

PackedAttention packed_cross_attention_row0(const torch::Tensor& q, const torch::Tensor& kv, int64_t heads,
                                            double scale, CpuVectorForm form) {
  TORCH_CHECK(q.dim() == 3 && kv.dim() == 3 && kv.size(2) == 2 * q.size(2) && q.size(0) == kv.size(0),
              "packed_cross_attention_row0: expected q (B, Lq, E) and kv (B, Lk, 2E), got ", q.sizes(), " and ",
              kv.sizes());
  return run(q, kv, torch::Tensor(), heads, q.size(2), scale, form, /*with_row0=*/true);
}

}  // namespace ablenerf
