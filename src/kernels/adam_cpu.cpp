#include "kernels/adam_cpu.h"

#include <cmath>
#include <stdexcept>

#include "kernels/cpu_features.h"

#ifdef ABLENERF_HAVE_AVX2_FORM
#include <immintrin.h>
#endif

namespace ablenerf {

namespace {

ABLENERF_SEPARATE_ROUNDINGS void update_scalar(int64_t lo, int64_t hi, const float* g, float* m, float* v, float* w,
                                               const AdamScalars& s) {
  for (int64_t j = lo; j < hi; ++j) {
    m[j] = m[j] * s.b1 + s.one_b1 * g[j];
    v[j] = v[j] * s.b2 + s.one_b2 * (g[j] * g[j]);
    const float denom = std::sqrt(v[j]) / s.sqrt_bias2 + s.eps;
    w[j] = w[j] + s.neg_step * (m[j] / denom);
  }
}

// Entries [lo, hi) of adam_update_decayed_cpu_in; the finite test as table_gradient's (g x 0 is 0
// for a finite g).
ABLENERF_SEPARATE_ROUNDINGS double update_decayed_scalar(int64_t lo, int64_t hi, const float* sum, float two_decay,
                                                         float* m, float* v, float* w, const AdamScalars& s,
                                                         bool& finite) {
  double sq = 0.0;
  for (int64_t j = lo; j < hi; ++j) {
    const float wj = w[j];
    sq += static_cast<double>(wj) * wj;
    const float g = sum[j] + two_decay * wj;
    if (g * 0.0f != 0.0f) {
      finite = false;
      continue;
    }
    m[j] = m[j] * s.b1 + s.one_b1 * g;
    v[j] = v[j] * s.b2 + s.one_b2 * (g * g);
    const float denom = std::sqrt(v[j]) / s.sqrt_bias2 + s.eps;
    w[j] = wj + s.neg_step * (m[j] / denom);
  }
  return sq;
}

#ifdef ABLENERF_HAVE_AVX2_FORM
// GCC 12 warns that its own AVX-512 sqrt intrinsic reads an uninitialised pass-through operand.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
ABLENERF_TARGET_AVX512 ABLENERF_SEPARATE_ROUNDINGS void update_avx512(int64_t n, const float* g, float* m, float* v,
                                                                      float* w, const AdamScalars& s) {
  const __m512 b1 = _mm512_set1_ps(s.b1), one_b1 = _mm512_set1_ps(s.one_b1), b2 = _mm512_set1_ps(s.b2),
               one_b2 = _mm512_set1_ps(s.one_b2), eps = _mm512_set1_ps(s.eps),
               sqrt_bias2 = _mm512_set1_ps(s.sqrt_bias2), neg_step = _mm512_set1_ps(s.neg_step);
  int64_t j = 0;
  for (; j + 16 <= n; j += 16) {
    const __m512 gj = _mm512_loadu_ps(g + j);
    // Products and sums as separate instructions: the scalar loop's roundings.
    const __m512 mj = _mm512_add_ps(_mm512_mul_ps(_mm512_loadu_ps(m + j), b1), _mm512_mul_ps(one_b1, gj));
    const __m512 vj =
        _mm512_add_ps(_mm512_mul_ps(_mm512_loadu_ps(v + j), b2), _mm512_mul_ps(one_b2, _mm512_mul_ps(gj, gj)));
    const __m512 denom = _mm512_add_ps(_mm512_div_ps(_mm512_sqrt_ps(vj), sqrt_bias2), eps);
    const __m512 wj = _mm512_add_ps(_mm512_loadu_ps(w + j), _mm512_mul_ps(neg_step, _mm512_div_ps(mj, denom)));
    _mm512_storeu_ps(m + j, mj);
    _mm512_storeu_ps(v + j, vj);
    _mm512_storeu_ps(w + j, wj);
  }
  update_scalar(j, n, g, m, v, w, s);
}

// 16 entries at a time; the squares in float64 in 16 lanes (another order of their sum than the
// scalar loop's); a lane whose g is not finite keeps its old values.
ABLENERF_TARGET_AVX512 ABLENERF_SEPARATE_ROUNDINGS double update_decayed_avx512(int64_t n, const float* sum,
                                                                                float two_decay, float* m, float* v,
                                                                                float* w, const AdamScalars& s,
                                                                                bool& finite) {
  const __m512 b1 = _mm512_set1_ps(s.b1), one_b1 = _mm512_set1_ps(s.one_b1), b2 = _mm512_set1_ps(s.b2),
               one_b2 = _mm512_set1_ps(s.one_b2), eps = _mm512_set1_ps(s.eps),
               sqrt_bias2 = _mm512_set1_ps(s.sqrt_bias2), neg_step = _mm512_set1_ps(s.neg_step),
               decay = _mm512_set1_ps(two_decay), zero = _mm512_setzero_ps();
  __m512d sq_low = _mm512_setzero_pd(), sq_high = _mm512_setzero_pd();
  __mmask16 bad = 0;
  int64_t j = 0;
  for (; j + 16 <= n; j += 16) {
    const __m512 wj = _mm512_loadu_ps(w + j);
    const __m512d w_low = _mm512_cvtps_pd(_mm512_castps512_ps256(wj));
    const __m512d w_high = _mm512_cvtps_pd(_mm512_castps512_ps256(_mm512_shuffle_f32x4(wj, wj, 0xEE)));
    sq_low = _mm512_add_pd(sq_low, _mm512_mul_pd(w_low, w_low));
    sq_high = _mm512_add_pd(sq_high, _mm512_mul_pd(w_high, w_high));
    const __m512 gj = _mm512_add_ps(_mm512_loadu_ps(sum + j), _mm512_mul_ps(decay, wj));
    // Lanes whose g is finite (g x 0 == 0); the others are not stored.
    const __mmask16 ok = _mm512_cmp_ps_mask(_mm512_mul_ps(gj, zero), zero, _CMP_EQ_OQ);
    bad |= static_cast<__mmask16>(~ok);
    const __m512 mj = _mm512_add_ps(_mm512_mul_ps(_mm512_loadu_ps(m + j), b1), _mm512_mul_ps(one_b1, gj));
    const __m512 vj =
        _mm512_add_ps(_mm512_mul_ps(_mm512_loadu_ps(v + j), b2), _mm512_mul_ps(one_b2, _mm512_mul_ps(gj, gj)));
    const __m512 denom = _mm512_add_ps(_mm512_div_ps(_mm512_sqrt_ps(vj), sqrt_bias2), eps);
    const __m512 w_new = _mm512_add_ps(wj, _mm512_mul_ps(neg_step, _mm512_div_ps(mj, denom)));
    _mm512_mask_storeu_ps(m + j, ok, mj);
    _mm512_mask_storeu_ps(v + j, ok, vj);
    _mm512_mask_storeu_ps(w + j, ok, w_new);
  }
  if (bad != 0) finite = false;
  alignas(64) double lanes[8];
  _mm512_store_pd(lanes, _mm512_add_pd(sq_low, sq_high));
  double sq = 0.0;
  for (const double lane : lanes) sq += lane;
  return sq + update_decayed_scalar(j, n, sum, two_decay, m, v, w, s, finite);
}
#pragma GCC diagnostic pop
#endif

}  // namespace

void adam_update_cpu_in(CpuVectorForm form, int64_t n, const float* g, float* m, float* v, float* w,
                        const AdamScalars& s) {
  if (!cpu_vector_form_available(form)) throw std::invalid_argument("adam: AVX-512 form on a CPU without it");
#ifdef ABLENERF_HAVE_AVX2_FORM
  if (form == CpuVectorForm::Avx512) return update_avx512(n, g, m, v, w, s);
#endif
  update_scalar(0, n, g, m, v, w, s);
}

void adam_update_cpu(int64_t n, const float* g, float* m, float* v, float* w, const AdamScalars& s) {
  adam_update_cpu_in(cpu_best_vector_form(), n, g, m, v, w, s);
}

double adam_update_decayed_cpu_in(CpuVectorForm form, int64_t n, const float* sum, float two_decay, float* m, float* v,
                                  float* w, const AdamScalars& s, bool& finite) {
  if (!cpu_vector_form_available(form)) throw std::invalid_argument("adam: AVX-512 form on a CPU without it");
#ifdef ABLENERF_HAVE_AVX2_FORM
  if (form == CpuVectorForm::Avx512) return update_decayed_avx512(n, sum, two_decay, m, v, w, s, finite);
#endif
  return update_decayed_scalar(0, n, sum, two_decay, m, v, w, s, finite);
}

}  // namespace ablenerf
