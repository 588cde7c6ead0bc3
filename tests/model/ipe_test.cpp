// Stage 2: integrated positional encoding against closed forms and a Monte-Carlo expectation.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>

#include "model/ipe.h"

namespace ablenerf {
namespace {

TEST(Ipe, WidthAndOrderWithVanishingVariance) {
  const int64_t degrees = 16;
  const auto opts = torch::TensorOptions(torch::kDouble);
  const auto mean = torch::tensor({0.31, -1.27, 0.05, 1.9, 0.7, -0.4}, opts).view({2, 3});
  const auto enc = integrated_pos_enc(mean, torch::zeros_like(mean), degrees);
  ASSERT_EQ(enc.sizes(), (std::vector<int64_t>{2, 96}));
  const auto a = enc.accessor<double, 2>();
  for (int n = 0; n < 2; ++n)
    for (int l = 0; l < degrees; ++l)
      for (int c = 0; c < 3; ++c) {
        const double y = std::ldexp(mean[n][c].item<double>(), l);
        EXPECT_NEAR(a[n][3 * l + c], std::sin(y), 1e-9) << n << " " << l << " " << c;
        EXPECT_NEAR(a[n][48 + 3 * l + c], std::cos(y), 1e-9) << n << " " << l << " " << c;
      }
}

TEST(Ipe, MatchesMonteCarloExpectationUnderLargeVariance) {
  const int64_t degrees = 6, samples = 200000;
  const auto opts = torch::TensorOptions(torch::kDouble);
  const auto mean = torch::tensor({0.3, -1.1, 0.7}, opts);
  const auto var = torch::tensor({0.01, 0.002, 0.05}, opts);
  const auto enc = integrated_pos_enc(mean.view({1, 3}), var.view({1, 3}), degrees)[0];
  auto gen = at::detail::createCPUGenerator(1234);
  const auto x = mean + var.sqrt() * torch::randn({samples, 3}, gen, opts);
  // Standard error of a mean of values bounded by 1 is <= 1/sqrt(N); allow 5 of them.
  const double tol = 5.0 / std::sqrt(static_cast<double>(samples));
  for (int l = 0; l < degrees; ++l) {
    const auto y = x * std::ldexp(1.0, l);
    for (int c = 0; c < 3; ++c) {
      EXPECT_NEAR(enc[3 * l + c].item<double>(), torch::sin(y.select(1, c)).mean().item<double>(), tol) << l << c;
      EXPECT_NEAR(enc[3 * degrees + 3 * l + c].item<double>(), torch::cos(y.select(1, c)).mean().item<double>(), tol)
          << l << c;
    }
  }
}

}  // namespace
}  // namespace ablenerf
