// GELU and its derivative in one pass (kernels/gelu_cpu.h) against the closed forms computed in
// float64 with the C library's erf and exp, on every path this CPU runs (the scalar one always, so
// the fallback of a CPU without AVX2 is tested everywhere), over the range where GELU bends, its
// tails (where erf saturates and exp underflows) and lengths that leave a partial vector.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "kernels/gelu_cpu.h"

namespace ablenerf {
namespace {

double gelu_exact(double a) { return 0.5 * a * (1 + std::erf(a / std::sqrt(2.0))); }
double gelu_derivative_exact(double a) {
  return 0.5 * (1 + std::erf(a / std::sqrt(2.0))) + a * std::exp(-0.5 * a * a) / std::sqrt(2 * M_PI);
}

TEST(GeluCpu, EveryPathMatchesTheClosedForms) {
  std::vector<float> a;
  for (int i = -4000; i <= 4000; ++i) a.push_back(float(i) * 0.0025f);  // [-10, 10]
  for (const float v : {-40.0f, -15.0f, 15.0f, 40.0f, 0.0f, -0.0f, 1e-20f}) a.push_back(v);
  int ran = 0;
  for (const GeluPath path : {GeluPath::Scalar, GeluPath::Avx2, GeluPath::Avx512, GeluPath::Auto}) {
    if (!gelu_cpu_path_available(path)) continue;
    ++ran;
    for (const int64_t n : {int64_t(a.size()), int64_t(1), int64_t(7), int64_t(17), int64_t(31)}) {
      std::vector<float> g(a.size(), NAN), d(a.size(), NAN);
      gelu_and_derivative(a.data(), g.data(), d.data(), n, path);
      for (int64_t i = 0; i < n; ++i) {
        const double x = a[size_t(i)];
        // Relative to the value where it is large; absolute near zero (float rounding of x itself).
        EXPECT_NEAR(g[size_t(i)], gelu_exact(x), 2e-6 * std::max(1.0, std::abs(x)))
            << gelu_cpu_path_name(path) << " " << x;
        EXPECT_NEAR(d[size_t(i)], gelu_derivative_exact(x), 4e-6) << gelu_cpu_path_name(path) << " " << x;
      }
      // Nothing past n is written.
      if (n < int64_t(a.size())) EXPECT_TRUE(std::isnan(g[size_t(n)]) && std::isnan(d[size_t(n)]));
    }
  }
  EXPECT_GE(ran, 2);  // the scalar path and Auto at least
}

TEST(GeluCpu, APathTheCpuCannotRunIsRefused) {
  float a = 1, g = 0, d = 0;
  for (const GeluPath path : {GeluPath::Avx2, GeluPath::Avx512})
    if (!gelu_cpu_path_available(path)) EXPECT_THROW(gelu_and_derivative(&a, &g, &d, 1, path), std::invalid_argument);
  EXPECT_NE(gelu_cpu_best_path(), GeluPath::Auto);
  EXPECT_TRUE(gelu_cpu_path_available(gelu_cpu_best_path()));
}

}  // namespace
}  // namespace ablenerf
