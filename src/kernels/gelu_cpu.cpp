#include "kernels/gelu_cpu.h"

#include <cmath>
#include <stdexcept>
#include <string>

#include "kernels/cpu_features.h"

#if defined(ABLENERF_HAVE_SLEEF) && defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define ABLENERF_GELU_SLEEF 1
#include <immintrin.h>
// Sleef's vector functions for AVX-512 and AVX2. sleef.h declares them only in a translation unit
// compiled for those instructions as a whole; this one is compiled for the baseline and enables
// them per function after a run-time check, so the two pairs it calls are declared here.
#pragma GCC push_options
#pragma GCC target("avx512f,avx2,fma")
extern "C" {
__m512 Sleef_expf16_u10avx512f(__m512);
__m256 Sleef_expf8_u10avx2(__m256);
}
#pragma GCC pop_options
#include "kernels/erfc_approx.h"
#endif

namespace ablenerf {

// Named: the unity build compiles this file with the other kernels.
namespace gelu_cpu_impl {

constexpr float kInvSqrt2 = 0.70710678118654752f;    // 1 / sqrt 2
constexpr float kInvSqrt2Pi = 0.39894228040143268f;  // 1 / sqrt(2 pi)

void gelu_scalar(const float* a, float* g, float* d, int64_t n) {
  for (int64_t i = 0; i < n; ++i) {
    const float x = a[i];
    const float phi_cdf = 0.5f * (1.0f + std::erf(x * kInvSqrt2));
    g[i] = x * phi_cdf;
    d[i] = phi_cdf + x * kInvSqrt2Pi * std::exp(-0.5f * x * x);
  }
}

#ifdef ABLENERF_GELU_SLEEF
// The vector forms take Phi from the same exp(-a^2 / 2) that phi needs (kernels/erfc_approx.h):
// Phi(a) = 1 - erfc(z) / 2 for a >= 0 and erfc(z) / 2 below, z = |a| / sqrt 2. Sleef's 1-ulp erf had taken 29% of the
// fused block tail's forward, against 1% for its exp (docs/benchmarks/history.md, "Row loops in vectors").
__attribute__((target("avx512f"))) void gelu_avx512(const float* a, float* g, float* d, int64_t n) {
  const __m512 half = _mm512_set1_ps(0.5f), one = _mm512_set1_ps(1.0f), r2 = _mm512_set1_ps(kInvSqrt2),
               r2pi = _mm512_set1_ps(kInvSqrt2Pi), minus_half = _mm512_set1_ps(-0.5f), zero = _mm512_setzero_ps();
  int64_t i = 0;
  for (; i + 16 <= n; i += 16) {
    const __m512 x = _mm512_loadu_ps(a + i);
    const __m512 e = Sleef_expf16_u10avx512f(_mm512_mul_ps(minus_half, _mm512_mul_ps(x, x)));
    const __m512 z = _mm512_abs_ps(_mm512_mul_ps(x, r2));
    const __m512 tail = _mm512_mul_ps(half, _mm512_mul_ps(erfc_approx::factor16(z), e));  // erfc(z) / 2
    const __mmask16 positive = _mm512_cmp_ps_mask(x, zero, _CMP_GE_OQ);
    const __m512 cdf = _mm512_mask_sub_ps(tail, positive, one, tail);
    _mm512_storeu_ps(g + i, _mm512_mul_ps(x, cdf));
    _mm512_storeu_ps(d + i, _mm512_fmadd_ps(x, _mm512_mul_ps(r2pi, e), cdf));
  }
  gelu_scalar(a + i, g + i, d + i, n - i);
}

__attribute__((target("avx2,fma"))) void gelu_avx2(const float* a, float* g, float* d, int64_t n) {
  const __m256 half = _mm256_set1_ps(0.5f), one = _mm256_set1_ps(1.0f), r2 = _mm256_set1_ps(kInvSqrt2),
               r2pi = _mm256_set1_ps(kInvSqrt2Pi), minus_half = _mm256_set1_ps(-0.5f), zero = _mm256_setzero_ps(),
               sign = _mm256_set1_ps(-0.0f);
  int64_t i = 0;
  for (; i + 8 <= n; i += 8) {
    const __m256 x = _mm256_loadu_ps(a + i);
    const __m256 e = Sleef_expf8_u10avx2(_mm256_mul_ps(minus_half, _mm256_mul_ps(x, x)));
    const __m256 z = _mm256_andnot_ps(sign, _mm256_mul_ps(x, r2));
    const __m256 tail = _mm256_mul_ps(half, _mm256_mul_ps(erfc_approx::factor8(z), e));
    const __m256 cdf = _mm256_blendv_ps(tail, _mm256_sub_ps(one, tail), _mm256_cmp_ps(x, zero, _CMP_GE_OQ));
    _mm256_storeu_ps(g + i, _mm256_mul_ps(x, cdf));
    _mm256_storeu_ps(d + i, _mm256_fmadd_ps(x, _mm256_mul_ps(r2pi, e), cdf));
  }
  gelu_scalar(a + i, g + i, d + i, n - i);
}
#endif

}  // namespace gelu_cpu_impl

using gelu_cpu_impl::gelu_scalar;
#ifdef ABLENERF_GELU_SLEEF
using gelu_cpu_impl::gelu_avx2;
using gelu_cpu_impl::gelu_avx512;
#endif

bool gelu_cpu_path_available(GeluPath path) {
  switch (path) {
    case GeluPath::Auto:
    case GeluPath::Scalar: return true;
#ifdef ABLENERF_GELU_SLEEF
    case GeluPath::Avx512: return cpu_has_avx512();
    case GeluPath::Avx2: return cpu_has_avx2_fma();
#endif
    default: return false;
  }
}

GeluPath gelu_cpu_best_path() {
  static const GeluPath best = gelu_cpu_path_available(GeluPath::Avx512) ? GeluPath::Avx512
                               : gelu_cpu_path_available(GeluPath::Avx2) ? GeluPath::Avx2
                                                                         : GeluPath::Scalar;
  return best;
}

const char* gelu_cpu_path_name(GeluPath path) {
  switch (path) {
    case GeluPath::Auto: return gelu_cpu_path_name(gelu_cpu_best_path());
    case GeluPath::Avx512: return "avx512 (Sleef exp)";
    case GeluPath::Avx2: return "avx2 (Sleef exp)";
    case GeluPath::Scalar: return "scalar";
  }
  return "scalar";
}

void gelu_and_derivative(const float* a, float* g, float* d, int64_t n, GeluPath path) {
  if (path == GeluPath::Auto) path = gelu_cpu_best_path();
  if (!gelu_cpu_path_available(path))
    throw std::invalid_argument(std::string("gelu_and_derivative: the ") + gelu_cpu_path_name(path) +
                                " path cannot run on this CPU or build");
  switch (path) {
#ifdef ABLENERF_GELU_SLEEF
    case GeluPath::Avx512: return gelu_avx512(a, g, d, n);
    case GeluPath::Avx2: return gelu_avx2(a, g, d, n);
#endif
    default: return gelu_scalar(a, g, d, n);
  }
}

}  // namespace ablenerf
