#include "kernels/vector_exp.h"

#include <cstring>
#include <limits>

#include "kernels/cpu_features.h"

namespace ablenerf {

namespace {

typedef float ExpF8 __attribute__((vector_size(32)));
typedef int32_t ExpI8 __attribute__((vector_size(32)));

// Eight exponentials in place (no vector crosses a call: its ABI would differ with and without AVX).
ABLENERF_ALWAYS_INLINE void exp8(float* p) {
  const ExpF8 zero = {};
  ExpF8 x;
  std::memcpy(&x, p, sizeof(ExpF8));
  const ExpF8 lo = zero - 87.33654f, hi = zero + 88.72283f;  // ln of the smallest normal, of FLT_MAX
  const ExpI8 under = x<lo, over = x> hi;
  x = under ? lo : x;
  x = over ? hi : x;
  // n = floor(x / ln2 + 1/2): truncation, then one down where it rounded a negative value up.
  const ExpF8 t = x * 1.44269504088896341f + 0.5f;
  ExpI8 n = __builtin_convertvector(t, ExpI8);
  n += __builtin_convertvector(n, ExpF8) > t;  // comparison lanes are -1 where true
  const ExpF8 nf = __builtin_convertvector(n, ExpF8);
  // r = x - n ln2, with ln2 = 0.693359375 - 2.12194440e-4 (the first part exact in few bits).
  ExpF8 r = x - nf * 0.693359375f;
  r = r + nf * 2.12194440e-4f;
  ExpF8 y = zero + 1.9875691500e-4f;
  y = y * r + 1.3981999507e-3f;
  y = y * r + 8.3334519073e-3f;
  y = y * r + 4.1665795894e-2f;
  y = y * r + 1.6666665459e-1f;
  y = y * r + 5.0000001201e-1f;
  y = y * (r * r) + r + 1.0f;
  // 2^n as two factors 2^h 2^(n-h), h = floor(n/2), each a float's exponent field: n reaches 128
  // just below FLT_MAX's log and -126 at the smallest normal, one past either end of one factor.
  const ExpI8 h = n >> 1;
  const ExpI8 bits_a = (h + 127) << 23, bits_b = (n - h + 127) << 23;
  ExpF8 scale_a, scale_b;
  std::memcpy(&scale_a, &bits_a, sizeof(ExpF8));
  std::memcpy(&scale_b, &bits_b, sizeof(ExpF8));
  ExpF8 out = y * scale_a * scale_b;
  out = under ? zero : out;
  out = over ? zero + std::numeric_limits<float>::infinity() : out;
  std::memcpy(p, &out, sizeof(ExpF8));
}

ABLENERF_ALWAYS_INLINE void exp_body(float* x, int64_t n) {
  int64_t i = 0;
  for (; i + 8 <= n; i += 8) exp8(x + i);
  if (i < n) {
    float tail[8] = {};
    const size_t rest = static_cast<size_t>(n - i) * sizeof(float);
    std::memcpy(tail, x + i, rest);
    exp8(tail);
    std::memcpy(x + i, tail, rest);
  }
}

}  // namespace

void exp_inplace_baseline(float* x, int64_t n) { exp_body(x, n); }

namespace {

#ifdef ABLENERF_HAVE_AVX2_FORM
ABLENERF_TARGET_AVX2 void exp_avx2(float* x, int64_t n) { exp_body(x, n); }
#endif

}  // namespace

void exp_inplace(float* x, int64_t n) {
#ifdef ABLENERF_HAVE_AVX2_FORM
  if (cpu_has_avx2_fma()) return exp_avx2(x, n);
#endif
  exp_inplace_baseline(x, n);
}

}  // namespace ablenerf
