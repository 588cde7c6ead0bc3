#pragma once
// exp over float arrays, eight lanes at a time: the attention softmax's exponentials (74,000 per
// attention call and ray slice at the demo preset), which the C library's scalar expf computes one
// by one in ~20 cycles each.
//
// Method (Cephes' expf): x = n ln2 + r with n = round(x / ln2) and ln2 split in two parts so that
// r is exact to float precision, exp(r) by a degree-6 polynomial on |r| <= ln2 / 2, then 2^n placed
// in the exponent bits. Relative error within a few float ulps of the correctly rounded value for
// x in [-87.3, 88.7]; below -87.3 (where exp is smaller than the smallest normal float), including
// -inf, the result is 0; above 88.7, +inf; NaN stays NaN.
#include <cstdint>

namespace ablenerf {

// x[i] <- exp(x[i]) for i < n.
void exp_inplace(float* x, int64_t n);

// The same with the baseline instructions whatever the CPU (the tests check both forms;
// exp_inplace picks the AVX2 + FMA one where kernels/cpu_features.h finds it).
void exp_inplace_baseline(float* x, int64_t n);

}  // namespace ablenerf
