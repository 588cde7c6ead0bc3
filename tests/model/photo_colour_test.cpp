// Per-photo colour (model/photo_colour.h): the identity at the start, each ray mapped by its own
// photo's affine map minus the maps' mean (against a hand computation), and weights that carry the maps bring them back
// into a model made without them.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include "model/able_nerf.h"
#include "model/model_config.h"
#include "model/photo_colour.h"
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
    pc->delta()[1][0][0] = 1.0f;
    pc->delta()[1][1][2] = 0.5f;
    pc->delta()[1][2][3] = -0.1f;
    pc->delta()[2].copy_(-pc->delta()[1]);
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
    pc->delta().add_(torch::randn({3, 4}));
  }
  EXPECT_TRUE(torch::allclose(pc(rgb, photo), out, 0, 1e-5));
  EXPECT_THROW(PhotoColour(0), std::invalid_argument);
}

TEST(PhotoColour, WeightsCarryTheMapsIntoAModelMadeWithoutThem) {
  test::TempDir dir;
  ModelConfig cfg;
  cfg.width = 16;
  cfg.heads = 2;
  cfg.samples = 4;
  cfg.le_count = 2;
  AbleNerf a(cfg);
  a->enable_photo_colour(5);
  {
    torch::NoGradGuard no_grad;
    a->photo_colour()->delta().copy_(torch::randn({5, 3, 4}));
  }
  EXPECT_THROW(a->enable_photo_colour(5), std::logic_error);
  save_weights(a, dir / "w.pt");
  AbleNerf b(cfg);
  ASSERT_EQ(b->photo_colour(), nullptr);
  load_weights(b, dir / "w.pt");
  ASSERT_NE(b->photo_colour(), nullptr);
  EXPECT_TRUE(torch::equal(b->photo_colour()->delta(), a->photo_colour()->delta()));
  // Rendering never reads them: with b's maps zeroed the two models' colours still agree.
  const auto rays = test::random_rays(6, 3, torch::kFloat);
  torch::NoGradGuard no_grad;
  b->photo_colour()->delta().zero_();
  a->eval();
  b->eval();
  EXPECT_TRUE(torch::allclose(a->forward(rays, 2.0, 6.0).rgb_fine, b->forward(rays, 2.0, 6.0).rgb_fine));
}

}  // namespace
}  // namespace ablenerf
