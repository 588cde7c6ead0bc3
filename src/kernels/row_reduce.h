#pragma once
// Sums and maxima along one short row (a token's features, a query's scores) without a serial
// chain of operations.
//
// A plain `for (j) s += x[j]` is one dependency chain: each add waits for the previous one, and
// the compiler may not reorder float sums to vectorise it. At the CPU presets' widths (E = 32
// features, 17 keys) such row sums held the fused block tail's LayerNorms at a fraction of what its
// products run at (docs/benchmarks/history.md, "Row loops in vectors"). Here float rows are taken
// 16 elements at a time into one vector of partial sums (GCC/Clang vector extensions: one AVX-512
// register, or four SSE registers in a baseline build), folded in halves at the end, then the
// elements after the last whole vector are added. The result differs from the serial sum by
// rounding only (another summation order). Double rows keep the plain loop (tests only).
#include <algorithm>
#include <cstdint>

#include "kernels/cpu_features.h"

namespace ablenerf {

namespace row_reduce_detail {
typedef float Row16 __attribute__((vector_size(64)));
typedef float Row16u __attribute__((vector_size(64), aligned(4), may_alias));
typedef float Row8 __attribute__((vector_size(32)));
typedef float Row4 __attribute__((vector_size(16)));

// The 16 floats from x (any float alignment). A macro, not a function: a 64-byte vector passed or
// returned by value draws GCC's note on that ABI in a baseline build.
#define ABLENERF_ROW16(x) (*reinterpret_cast<const row_reduce_detail::Row16u*>(x))

ABLENERF_ALWAYS_INLINE float fold_sum(const Row16& v) {
  const Row8 a = __builtin_shufflevector(v, v, 0, 1, 2, 3, 4, 5, 6, 7) +
                 __builtin_shufflevector(v, v, 8, 9, 10, 11, 12, 13, 14, 15);
  const Row4 b = __builtin_shufflevector(a, a, 0, 1, 2, 3) + __builtin_shufflevector(a, a, 4, 5, 6, 7);
  return (b[0] + b[2]) + (b[1] + b[3]);
}

ABLENERF_ALWAYS_INLINE float fold_max(const Row16& v) {
  float m = v[0];
  for (int l = 1; l < 16; ++l) m = std::max(m, v[l]);
  return m;
}
}  // namespace row_reduce_detail

// sum_j x[j] over j in [0, n).
ABLENERF_ALWAYS_INLINE float row_sum(const float* x, int64_t n) {
  using namespace row_reduce_detail;
  Row16 acc = {};
  int64_t j = 0;
  for (; j + 16 <= n; j += 16) acc += ABLENERF_ROW16(x + j);
  float s = fold_sum(acc);
  for (; j < n; ++j) s += x[j];
  return s;
}

// sum_j x[j] y[j] over j in [0, n).
ABLENERF_ALWAYS_INLINE float row_dot(const float* x, const float* y, int64_t n) {
  using namespace row_reduce_detail;
  Row16 acc = {};
  int64_t j = 0;
  for (; j + 16 <= n; j += 16) acc += ABLENERF_ROW16(x + j) * ABLENERF_ROW16(y + j);
  float s = fold_sum(acc);
  for (; j < n; ++j) s += x[j] * y[j];
  return s;
}

// max_j x[j] over j in [0, n), n >= 1.
ABLENERF_ALWAYS_INLINE float row_max(const float* x, int64_t n) {
  using namespace row_reduce_detail;
  float m = x[0];
  int64_t j = 0;
  if (n >= 16) {
    Row16 acc = ABLENERF_ROW16(x);
    for (j = 16; j + 16 <= n; j += 16) {
      const Row16 v = ABLENERF_ROW16(x + j);
      acc = acc > v ? acc : v;
    }
    m = fold_max(acc);
  }
  for (; j < n; ++j) m = std::max(m, x[j]);
  return m;
}

ABLENERF_ALWAYS_INLINE double row_sum(const double* x, int64_t n) {
  double s = 0;
  for (int64_t j = 0; j < n; ++j) s += x[j];
  return s;
}
ABLENERF_ALWAYS_INLINE double row_dot(const double* x, const double* y, int64_t n) {
  double s = 0;
  for (int64_t j = 0; j < n; ++j) s += x[j] * y[j];
  return s;
}
ABLENERF_ALWAYS_INLINE double row_max(const double* x, int64_t n) {
  double m = x[0];
  for (int64_t j = 1; j < n; ++j) m = std::max(m, x[j]);
  return m;
}

}  // namespace ablenerf
