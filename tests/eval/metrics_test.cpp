// PSNR / SSIM against hand-computed values and an independent double-precision loop SSIM.
// The `ablenerf metrics` command is tested in tests/cli/metrics_test.cpp.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <limits>
#include <vector>

#include "eval/metrics.h"
#include "test_util.h"
#include "util/errors.h"
#include "util/image_io.h"
#include "eval/eval_config.h"

namespace ablenerf {
namespace {

constexpr double kC1 = 0.01 * 0.01;
constexpr double kC2 = 0.03 * 0.03;

torch::Tensor constant_image(int64_t h, int64_t w, double v) { return torch::full({h, w, 3}, v, torch::kDouble); }

// ---- PSNR -----------------------------------------------------------------------------------

TEST(Psnr, ConstantOffsetOfOneTenthIsTwentyDecibels) {
  // MSE = 0.01 -> -10 log10(0.01) = 20 exactly.
  EXPECT_NEAR(psnr(constant_image(8, 9, 0.6), constant_image(8, 9, 0.5)), 20.0, 1e-9);
  // float32 inputs: 0.6f - 0.5f is 0.1 only to ~1e-8, so ~1e-6 dB.
  EXPECT_NEAR(psnr(constant_image(8, 9, 0.6).to(torch::kFloat), constant_image(8, 9, 0.5).to(torch::kFloat)), 20.0,
              1e-5);
}

TEST(Psnr, HalfThePixelsInOneChannel) {
  // 4x4x3 image; 8 of the 48 values differ by 0.5 -> MSE = 8 * 0.25 / 48 = 1/24.
  auto ref = torch::zeros({4, 4, 3}, torch::kDouble);
  auto img = ref.clone();
  img.slice(0, 0, 2).select(2, 1).fill_(0.5);
  EXPECT_NEAR(mse(img, ref), 1.0 / 24.0, 1e-15);
  EXPECT_NEAR(psnr(img, ref), 10.0 * std::log10(24.0), 1e-12);
}

TEST(Psnr, IdenticalImagesGiveInfinity) {
  auto a = torch::rand({5, 6, 3});
  EXPECT_EQ(psnr(a, a), std::numeric_limits<double>::infinity());
}

TEST(Psnr, FromMseClosedForms) {
  EXPECT_NEAR(psnr_from_mse(0.01), 20.0, 1e-12);
  EXPECT_NEAR(psnr_from_mse(1.0), 0.0, 1e-15);
  EXPECT_NEAR(psnr_from_mse(1.0 / 24.0), 10.0 * std::log10(24.0), 1e-12);
  EXPECT_EQ(psnr_from_mse(0.0), std::numeric_limits<double>::infinity());
}

TEST(Psnr, ShapeMismatchIsRejected) {
  EXPECT_THROW(psnr(torch::zeros({4, 4, 3}), torch::zeros({4, 5, 3})), c10::Error);
}

// ---- SSIM -----------------------------------------------------------------------------------

// Independent reference: explicit 11x11 window sums in double, per channel. `pad` = 0 is the
// valid (standard) map; `pad` = 5 zero-pads the images (release variant). No clamping: on the
// random images used here variances are far from 0, where multinerf's clamp is inactive.
double loop_ssim(const torch::Tensor& a_in, const torch::Tensor& b_in, int pad) {
  const int window = 11, half = 5;
  const double sigma = 1.5;
  double g[11], gsum = 0;
  for (int k = 0; k < window; ++k) {
    g[k] = std::exp(-double((k - half) * (k - half)) / (2 * sigma * sigma));
    gsum += g[k];
  }
  for (double& v : g) v /= gsum;
  auto a = a_in.to(torch::kDouble).contiguous(), b = b_in.to(torch::kDouble).contiguous();
  const int h = a.size(0), w = a.size(1), c = a.size(2);
  auto A = a.accessor<double, 3>(), B = b.accessor<double, 3>();
  auto at = [&](decltype(A)& t, int y, int x, int ch) {
    return (y < 0 || y >= h || x < 0 || x >= w) ? 0.0 : t[y][x][ch];
  };
  double total = 0;
  int count = 0;
  for (int ch = 0; ch < c; ++ch)
    for (int y0 = -pad; y0 + window <= h + pad; ++y0)
      for (int x0 = -pad; x0 + window <= w + pad; ++x0) {
        double mx = 0, my = 0, sxx = 0, syy = 0, sxy = 0;
        for (int i = 0; i < window; ++i)
          for (int j = 0; j < window; ++j) {
            const double wt = g[i] * g[j];
            const double x = at(A, y0 + i, x0 + j, ch), yv = at(B, y0 + i, x0 + j, ch);
            mx += wt * x;
            my += wt * yv;
            sxx += wt * x * x;
            syy += wt * yv * yv;
            sxy += wt * x * yv;
          }
        const double vx = sxx - mx * mx, vy = syy - my * my, cov = sxy - mx * my;
        total += ((2 * mx * my + kC1) * (2 * cov + kC2)) / ((mx * mx + my * my + kC1) * (vx + vy + kC2));
        ++count;
      }
  return total / count;
}

TEST(Ssim, ImageWithItselfIsOne) {
  torch::manual_seed(1);
  auto a = torch::rand({20, 17, 3});
  EXPECT_NEAR(ssim(a, a, SsimVariant::Standard), 1.0, 1e-12);
  EXPECT_NEAR(ssim(a, a, SsimVariant::Release), 1.0, 1e-12);
}

TEST(Ssim, ConstantImagesMatchClosedForm) {
  // Variances and covariance are zero, so SSIM = (2 c1 c2 + C1) / (c1^2 + c2^2 + C1).
  const double u = 0.3, v = 0.7;
  const double expected = (2 * u * v + kC1) / (u * u + v * v + kC1);
  EXPECT_NEAR(ssim(constant_image(13, 12, u), constant_image(13, 12, v), SsimVariant::Standard), expected, 1e-12);
}

TEST(Ssim, StandardMatchesLoopReference) {
  torch::manual_seed(7);
  auto a = torch::rand({16, 16, 3});
  auto b = (a + 0.2 * torch::randn({16, 16, 3})).clamp(0, 1);
  EXPECT_NEAR(ssim(b, a, SsimVariant::Standard), loop_ssim(b, a, 0), 1e-6);
  // An unrelated pair too (low SSIM, so not just "close to 1").
  auto c = torch::rand({16, 16, 3});
  EXPECT_NEAR(ssim(c, a, SsimVariant::Standard), loop_ssim(c, a, 0), 1e-6);
}

TEST(Ssim, ReleaseMatchesZeroPaddedLoopReference) {
  torch::manual_seed(8);
  auto a = torch::rand({16, 14, 3});
  auto b = (a + 0.1 * torch::randn({16, 14, 3})).clamp(0, 1);
  EXPECT_NEAR(ssim(b, a, SsimVariant::Release), loop_ssim(b, a, 5), 1e-6);
}

TEST(Ssim, ReleaseVariantDiffersFromStandard) {
  torch::manual_seed(9);
  auto a = torch::rand({24, 24, 3});
  auto b = (a + 0.1 * torch::randn({24, 24, 3})).clamp(0, 1);
  const double s = ssim(b, a, SsimVariant::Standard), r = ssim(b, a, SsimVariant::Release);
  EXPECT_GT(std::abs(s - r), 1e-3);
}

TEST(Ssim, StandardNeedsAnElevenPixelWindow) {
  EXPECT_THROW(ssim(torch::rand({10, 20, 3}), torch::rand({10, 20, 3})), c10::Error);
  EXPECT_NO_THROW(ssim(torch::rand({10, 20, 3}), torch::rand({10, 20, 3}), SsimVariant::Release));
}

TEST(Ssim, ParsesVariantNames) {
  EXPECT_EQ(parse_ssim_variant("standard"), SsimVariant::Standard);
  EXPECT_EQ(parse_ssim_variant("release"), SsimVariant::Release);
  EXPECT_THROW(parse_ssim_variant("skimage"), InputError);
}

// ---- reading images -------------------------------------------------------------------------

TEST(ReadRgbForMetrics, CompositesRgbaOnWhite) {
  test::TempDir dir("metrics");
  auto rgba = torch::zeros({2, 2, 4}, torch::kUInt8);
  rgba.index_put_({0, 0}, torch::tensor({255, 0, 0, 255}, torch::kUInt8));  // opaque red
  rgba.index_put_({0, 1}, torch::tensor({0, 0, 0, 0}, torch::kUInt8));      // transparent -> white
  rgba.index_put_({1, 0}, torch::tensor({0, 0, 0, 51}, torch::kUInt8));     // 20% black -> 0.8
  write_png(dir / "a.png", rgba);
  auto im = read_rgb_for_metrics(dir / "a.png");
  ASSERT_EQ(im.sizes(), (std::vector<int64_t>{2, 2, 3}));
  EXPECT_TRUE(torch::allclose(im[0][0], torch::tensor({1.0f, 0.0f, 0.0f})));
  EXPECT_TRUE(torch::allclose(im[0][1], torch::ones({3})));
  EXPECT_TRUE(torch::allclose(im[1][0], torch::full({3}, 0.8f)));
}

}  // namespace
}  // namespace ablenerf

// The "unmasked" scores of eval: PSNR over the kept pixels by hand; SSIM over an all-true mask is
// the plain mean, and over one pixel it is the SSIM of the 11x11 window centred there (the
// standard variant of that crop has exactly one valid position).
TEST(Metrics, MaskedPsnrAndSsim) {
  torch::manual_seed(4);
  const auto a = torch::rand({20, 24, 3}, torch::kDouble),
             b = (a + 0.1 * torch::randn({20, 24, 3}, torch::kDouble)).clamp(0, 1);
  auto keep = torch::zeros({20, 24}, torch::kBool);
  keep.slice(0, 3, 9).slice(1, 2, 20).fill_(true);
  double sq = 0;
  int64_t count = 0;
  for (int r = 0; r < 20; ++r)
    for (int c = 0; c < 24; ++c)
      if (keep[r][c].item<bool>()) {
        for (int ch = 0; ch < 3; ++ch) sq += std::pow(a[r][c][ch].item<double>() - b[r][c][ch].item<double>(), 2);
        ++count;
      }
  EXPECT_NEAR(psnr(a, b, keep), -10 * std::log10(sq / (3.0 * static_cast<double>(count))), 1e-9);
  const auto all = torch::ones({20, 24}, torch::kBool);
  for (const auto v : {SsimVariant::Standard, SsimVariant::Release})
    EXPECT_NEAR(ssim(a, b, v, all), ssim(a, b, v), 1e-12);
  auto one = torch::zeros({20, 24}, torch::kBool);
  one[9][13] = true;
  const auto crop = [](const torch::Tensor& x) { return x.slice(0, 4, 15).slice(1, 8, 19); };
  EXPECT_NEAR(ssim(a, b, SsimVariant::Standard, one), ssim(crop(a), crop(b)), 1e-12);
  // No kept pixel: NaN, which eval writes as null.
  EXPECT_TRUE(std::isnan(psnr(a, b, torch::zeros({20, 24}, torch::kBool))));
}
