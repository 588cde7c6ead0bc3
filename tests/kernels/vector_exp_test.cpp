// The vector exp (kernels/vector_exp.h) against the C library's exp in float64: relative error
// within 4 float ulps over the whole normal range on a dense grid, exact 1 at 0, 0 below the
// smallest normal (and at -inf), +inf above FLT_MAX's log, NaN kept; every array length from 0 to
// 19 (whole vectors and the leftover elements) written exactly on its n elements; the form chosen
// for this CPU and the baseline-instruction form alike.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <vector>

#include "kernels/vector_exp.h"

namespace ablenerf {
namespace {

constexpr double kUlp = 1.1920928955078125e-7;  // 2^-23

// Each test runs the form chosen for this CPU and the baseline-instruction form.
using ExpFn = void (*)(float*, int64_t);
const ExpFn kForms[] = {&exp_inplace, &exp_inplace_baseline};

TEST(VectorExp, RelativeErrorWithinFourUlpsOverTheNormalRange) {
  std::vector<float> x;
  for (double v = -87.3; v <= 88.7; v += 1.0 / 1024) x.push_back(static_cast<float>(v));
  // The reduction's edges: around multiples of ln 2 / 2, where n changes.
  for (int k = -250; k <= 250; ++k)
    for (const double d : {-1e-6, 0.0, 1e-6}) x.push_back(static_cast<float>(k * 0.34657359027997264 + d));
  for (const ExpFn form : kForms) {
    std::vector<float> y = x;
    form(y.data(), static_cast<int64_t>(y.size()));
    double worst = 0;
    for (size_t i = 0; i < x.size(); ++i) {
      if (x[i] < -87.3f || x[i] > 88.7f) continue;
      const double want = std::exp(static_cast<double>(x[i]));
      worst = std::max(worst, std::abs(static_cast<double>(y[i]) - want) / want);
    }
    EXPECT_LT(worst, 4 * kUlp);
  }
  EXPECT_GT(x.size(), 170000u);
}

TEST(VectorExp, SpecialValues) {
  const float inf = std::numeric_limits<float>::infinity();
  for (const ExpFn form : kForms) {
    std::vector<float> x = {0.0f, -inf, -88.0f, -1000.0f, 89.0f, 1000.0f, inf, std::nanf(""), 1.0f, -1.0f};
    form(x.data(), static_cast<int64_t>(x.size()));
    EXPECT_EQ(x[0], 1.0f);
    EXPECT_EQ(x[1], 0.0f);
    EXPECT_EQ(x[2], 0.0f);
    EXPECT_EQ(x[3], 0.0f);
    EXPECT_EQ(x[4], inf);
    EXPECT_EQ(x[5], inf);
    EXPECT_EQ(x[6], inf);
    EXPECT_TRUE(std::isnan(x[7]));
    EXPECT_NEAR(x[8], std::exp(1.0), 4 * kUlp * std::exp(1.0));
    EXPECT_NEAR(x[9], std::exp(-1.0), 4 * kUlp * std::exp(-1.0));
  }
}

TEST(VectorExp, EveryLengthWritesExactlyItsElements) {
  for (const ExpFn form : kForms) {
    for (int64_t n = 0; n <= 19; ++n) {
      std::vector<float> x(static_cast<size_t>(n) + 3, 7.0f);
      for (int64_t i = 0; i < n; ++i) x[static_cast<size_t>(i)] = -0.25f * static_cast<float>(i);
      form(x.data(), n);
      for (int64_t i = 0; i < n; ++i)
        EXPECT_NEAR(x[static_cast<size_t>(i)], std::exp(-0.25 * static_cast<double>(i)), 4 * kUlp) << n << " " << i;
      for (size_t i = static_cast<size_t>(n); i < x.size(); ++i) EXPECT_EQ(x[i], 7.0f) << "length " << n;
    }
  }
}

}  // namespace
}  // namespace ablenerf
