// Stage 7: the sRGB curve and the clip, against hand-computed values.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include "model/tonemap.h"

namespace ablenerf {
namespace {

double srgb(double x) { return linear_to_srgb(torch::tensor({x}, torch::kDouble)).item<double>(); }

TEST(Tonemap, HandValues) {
  EXPECT_NEAR(srgb(0.0), 0.0, 1e-12);
  EXPECT_NEAR(srgb(1.0), 1.0, 1e-12);                  // 1.055 - 0.055
  EXPECT_NEAR(srgb(0.5), 0.7353569830524495, 1e-9);    // 1.055 * 0.5^(1/2.4) - 0.055
  EXPECT_NEAR(srgb(0.002), 0.02584, 1e-12);            // linear segment 12.92 x
  EXPECT_NEAR(srgb(0.18), 0.46135612950044164, 1e-9);  // 18% grey
}

TEST(Tonemap, ContinuousAtThreshold) {
  const double below = srgb(kSrgbLinearThreshold), above = srgb(kSrgbLinearThreshold + 1e-12);
  EXPECT_NEAR(below, 0.0404500, 1e-6);
  EXPECT_NEAR(below, above, 1e-6);
}

TEST(Tonemap, ClipsAndStopsGradientWhenSaturated) {
  auto ray = torch::tensor({0.9, 0.2, -0.1}, torch::TensorOptions(torch::kDouble).requires_grad(true));
  const auto le = torch::tensor({0.4, 0.1, 0.0}, torch::kDouble);
  const auto rgb = tonemap(ray, le);
  EXPECT_EQ(rgb[0].item<double>(), 1.0);
  EXPECT_NEAR(rgb[1].item<double>(), srgb(0.3), 1e-12);
  EXPECT_EQ(rgb[2].item<double>(), 0.0);
  rgb.sum().backward();
  EXPECT_EQ(ray.grad()[0].item<double>(), 0.0);
  EXPECT_GT(ray.grad()[1].item<double>(), 0.0);
  // No-LE ablation: the ray colour alone.
  EXPECT_NEAR(tonemap(torch::tensor({0.5}, torch::kDouble), torch::Tensor()).item<double>(), srgb(0.5), 1e-12);
}

}  // namespace
}  // namespace ablenerf
