#pragma once
// The vector forms' complementary error function, Abramowitz and Stegun's 7.1.26 (the form ATen's
// vectorised erf uses), for z >= 0:
//
//   erfc(z) = t (c1 + t (c2 + t (c3 + t (c4 + t c5)))) exp(-z^2),   t = 1 / (1 + p z),
//
// absolute error under 1.5e-7. The callers evaluate exp(-z^2) themselves, because they have it at
// hand or need it anyway (GELU's derivative, kernels/gelu_cpu.cpp; the grid's level weights,
// kernels/sample_encoding_cpu.cpp); the functions here give the factor in front of it. For
// translation units compiled for the baseline: each function carries its own target attribute.
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#include <immintrin.h>

namespace ablenerf {
namespace erfc_approx {

constexpr float kP = 0.3275911f;
constexpr float kC1 = 0.254829592f, kC2 = -0.284496736f, kC3 = 1.421413741f, kC4 = -1.453152027f, kC5 = 1.061405429f;

// t (c1 + t (c2 + ...)) for 16 values of z >= 0 (+inf gives 0).
__attribute__((target("avx512f"), always_inline)) inline __m512 factor16(__m512 z) {
  const __m512 one = _mm512_set1_ps(1.0f);
  const __m512 t = _mm512_div_ps(one, _mm512_fmadd_ps(_mm512_set1_ps(kP), z, one));
  __m512 poly = _mm512_fmadd_ps(t, _mm512_set1_ps(kC5), _mm512_set1_ps(kC4));
  poly = _mm512_fmadd_ps(t, poly, _mm512_set1_ps(kC3));
  poly = _mm512_fmadd_ps(t, poly, _mm512_set1_ps(kC2));
  poly = _mm512_fmadd_ps(t, poly, _mm512_set1_ps(kC1));
  return _mm512_mul_ps(t, poly);
}

// The same for 8 values (AVX2 + FMA).
__attribute__((target("avx2,fma"), always_inline)) inline __m256 factor8(__m256 z) {
  const __m256 one = _mm256_set1_ps(1.0f);
  const __m256 t = _mm256_div_ps(one, _mm256_fmadd_ps(_mm256_set1_ps(kP), z, one));
  __m256 poly = _mm256_fmadd_ps(t, _mm256_set1_ps(kC5), _mm256_set1_ps(kC4));
  poly = _mm256_fmadd_ps(t, poly, _mm256_set1_ps(kC3));
  poly = _mm256_fmadd_ps(t, poly, _mm256_set1_ps(kC2));
  poly = _mm256_fmadd_ps(t, poly, _mm256_set1_ps(kC1));
  return _mm256_mul_ps(t, poly);
}

}  // namespace erfc_approx
}  // namespace ablenerf
#endif
