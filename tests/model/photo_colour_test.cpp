// Per-photo colour (model/photo_colour.h): the identity at the start, each ray mapped by its own
// photo's affine map minus the maps' mean (against a hand computation), the gain form against the
// sRGB standard's values and closed-form gains in linear light, its gradient against finite
// differences, and weights that carry either form bring it back into a model made without it.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include "model/able_nerf.h"
#include "model/model_config.h"
#include "model/photo_colour.h"
#include "model/tonemap.h"
#include "test_util.h"

namespace ablenerf {
namespace {

TEST(PhotoColour, EachRayTakesItsPhotosAffineMap) {
  PhotoColour pc(3);
  const auto rgb = torch::tensor({{0.2f, 0.5f, 0.9f}, {0.1f, 0.3f, 0.4f}, {0.7f, 0.6f, 0.5f}, {0.0f, 1.0f, 0.25f}});
  const auto photo = torch::tensor({0, 1, 2, 1}, torch::kLong);
  EXPECT_TRUE(torch::equal(pc(rgb, photo), rgb));  // zero = the identity
  // Photo 1: red gain 2, green from blue 0.5, blue bias -0.1; photo 2 the opposite, so that the
  // maps' mean is zero and photo 0 keeps the identity.
  {
    torch::NoGradGuard no_grad;
    pc->parameter()[1][0][0] = 1.0f;
    pc->parameter()[1][1][2] = 0.5f;
    pc->parameter()[1][2][3] = -0.1f;
    pc->parameter()[2].copy_(-pc->parameter()[1]);
  }
  const auto out = pc(rgb, photo);
  EXPECT_TRUE(torch::equal(out[0], rgb[0]));
  for (const int64_t i : {1, 3}) {
    const float r = rgb[i][0].item<float>(), g = rgb[i][1].item<float>(), b = rgb[i][2].item<float>();
    EXPECT_FLOAT_EQ(out[i][0].item<float>(), 2 * r) << i;
    EXPECT_FLOAT_EQ(out[i][1].item<float>(), g + 0.5f * b) << i;
    EXPECT_FLOAT_EQ(out[i][2].item<float>(), b - 0.1f) << i;
  }
  const float r = rgb[2][0].item<float>(), g = rgb[2][1].item<float>(), b = rgb[2][2].item<float>();
  EXPECT_FLOAT_EQ(out[2][0].item<float>(), 0 * r);
  EXPECT_FLOAT_EQ(out[2][1].item<float>(), g - 0.5f * b);
  EXPECT_FLOAT_EQ(out[2][2].item<float>(), b + 0.1f);
  // The maps applied are centred: a common change of every map changes nothing.
  {
    torch::NoGradGuard no_grad;
    pc->parameter().add_(torch::randn({3, 4}));
  }
  EXPECT_TRUE(torch::allclose(pc(rgb, photo), out, 0, 1e-5));
  EXPECT_THROW(PhotoColour(0), std::invalid_argument);
}

// IEC 61966-2-1: the decoding's published points (sRGB 0.5 is 0.2140 of linear light, the segment
// joint 0.04045 is 0.003130) and the round trip through linear_to_srgb.
TEST(PhotoColour, SrgbDecodingInvertsTheModelsCurve) {
  const auto s = torch::tensor({0.0, 0.04045, 0.5, 1.0}, torch::kDouble);
  const auto lin = srgb_to_linear(s);
  EXPECT_NEAR(lin[0].item<double>(), 0.0, 1e-15);
  EXPECT_NEAR(lin[1].item<double>(), 0.0031308, 1e-6);
  EXPECT_NEAR(lin[2].item<double>(), 0.21404, 1e-5);
  EXPECT_NEAR(lin[3].item<double>(), 1.0, 1e-12);
  const auto grid = torch::linspace(0.0, 1.0, 1001, torch::kDouble);
  EXPECT_LT((linear_to_srgb(srgb_to_linear(grid)) - grid).abs().max().item<double>(), 1e-12);
}

// The gain form: a photo whose gains are (2, 1, 1/2) in linear light (after centring over three
// photos: log gains (ln 2, 0, -ln 2), (0, 0, 0) and (-ln 2, 0, ln 2) around a common offset) turns a
// colour whose linear light is (0.2, 0.3, 0.6) into srgb(0.4, 0.3, 0.3); 0.6 x 2 saturates at 1.
TEST(PhotoColour, GainsActOnTheLinearLight) {
  PhotoColour pc(3, PhotoColourMap::Gain);
  ASSERT_EQ(pc->parameter().sizes(), torch::IntArrayRef({3, 3}));
  const auto light = torch::tensor({{0.2, 0.3, 0.6}}, torch::kDouble).repeat({3, 1});
  const auto rgb = linear_to_srgb(light);
  const auto photo = torch::tensor({0, 1, 2}, torch::kLong);
  EXPECT_TRUE(torch::allclose(pc(rgb, photo), rgb, 0, 1e-12));  // the identity
  {
    torch::NoGradGuard no_grad;
    const double l2 = std::log(2.0);
    pc->parameter().copy_((torch::tensor({{l2, 0.0, -l2}, {0.0, 0.0, 0.0}, {-l2, 0.0, l2}}) + 0.37) /
                          kPhotoGainLrScale);
  }
  const auto out = pc(rgb, photo);
  const auto expect =
      linear_to_srgb(torch::tensor({{0.4, 0.3, 0.3}, {0.2, 0.3, 0.6}, {0.1, 0.3, 1.0}}, torch::kDouble));
  EXPECT_TRUE(torch::allclose(out, expect, 0, 1e-5)) << out << expect;
  EXPECT_EQ(out[2][2].item<double>(), 1.0);
}

// d(sum of w x out)/d(parameter) against central differences, in float64 (no point at the
// saturation's kink or at the sRGB curve's joint).
TEST(PhotoColour, GainGradientMatchesFiniteDifferences) {
  torch::manual_seed(3);
  PhotoColour pc(4, PhotoColourMap::Gain);
  pc->to(torch::kDouble);
  {
    torch::NoGradGuard no_grad;
    pc->parameter().copy_(torch::randn({4, 3}, torch::kDouble) * 0.3 / kPhotoGainLrScale);
  }
  const auto rgb = torch::rand({10, 3}, torch::kDouble) * 0.5 + 0.1;
  const auto photo = torch::tensor({0, 1, 2, 3, 0, 1, 2, 3, 1, 1}, torch::kLong);
  const auto w = torch::randn({10, 3}, torch::kDouble);
  const auto loss = [&] { return (pc(rgb, photo) * w).sum(); };
  loss().backward();
  const auto grad = pc->parameter().grad().clone();
  torch::NoGradGuard no_grad;
  const double h = 1e-6;
  for (int64_t p = 0; p < 4; ++p)
    for (int64_t c = 0; c < 3; ++c) {
      auto e = pc->parameter()[p][c];
      const double x = e.item<double>();
      e.fill_(x + h);
      const double up = loss().item<double>();
      e.fill_(x - h);
      const double down = loss().item<double>();
      e.fill_(x);
      EXPECT_NEAR(grad[p][c].item<double>(), (up - down) / (2 * h), 1e-7) << p << "," << c;
    }
}

TEST(PhotoColour, WeightsCarryTheMapsIntoAModelMadeWithoutThem) {
  test::TempDir dir;
  const ModelConfig cfg = test::small_le_model_config();
  AbleNerf a(cfg);
  a->enable_photo_colour(5);
  {
    torch::NoGradGuard no_grad;
    a->photo_colour()->parameter().copy_(torch::randn({5, 3, 4}));
  }
  EXPECT_THROW(a->enable_photo_colour(5), std::logic_error);
  save_weights(a, dir / "w.pt");
  AbleNerf b(cfg);
  ASSERT_EQ(b->photo_colour(), nullptr);
  load_weights(b, dir / "w.pt");
  ASSERT_NE(b->photo_colour(), nullptr);
  EXPECT_TRUE(torch::equal(b->photo_colour()->parameter(), a->photo_colour()->parameter()));
  // Rendering never reads them: with b's maps zeroed the two models' colours still agree.
  const auto rays = test::random_rays(6, 3, torch::kFloat);
  torch::NoGradGuard no_grad;
  b->photo_colour()->parameter().zero_();
  a->eval();
  b->eval();
  EXPECT_TRUE(torch::allclose(a->forward(rays, 2.0, 6.0).rgb_fine, b->forward(rays, 2.0, 6.0).rgb_fine));
}

TEST(PhotoColour, WeightsCarryGainsIntoAModelMadeWithoutThem) {
  test::TempDir dir;
  const ModelConfig cfg = test::small_le_model_config();
  AbleNerf a(cfg);
  a->enable_photo_colour(3, PhotoColourMap::Gain);
  {
    torch::NoGradGuard no_grad;
    a->photo_colour()->parameter().copy_(torch::randn({3, 3}));
  }
  save_weights(a, dir / "w.pt");
  AbleNerf b(cfg);
  load_weights(b, dir / "w.pt");
  ASSERT_NE(b->photo_colour(), nullptr);
  EXPECT_EQ(b->photo_colour()->map(), PhotoColourMap::Gain);
  EXPECT_TRUE(torch::equal(b->photo_colour()->parameter(), a->photo_colour()->parameter()));
}

}  // namespace
}  // namespace ablenerf
