// Per-photo appearance codes (model/appearance_code.h): centred codes (against a hand computation),
// entering the view token only (the ray token's colour and the attention unchanged, the LE colour
// moved), one code for every ray the same as that code on each ray, per-ray codes cut with the
// CPU ray split, the codes' gradient (centred: it sums to zero over the photos), weights that carry
// them into a model made without them, and the refusals.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <stdexcept>

#include "model/able_nerf.h"
#include "model/appearance_code.h"
#include "model/look.h"
#include "model/model_config.h"
#include "test_util.h"
#include "util/errors.h"

namespace ablenerf {
namespace {

TEST(AppearanceCode, CodesAreCentredOverThePhotos) {
  AppearanceCode codes(3, 2);
  const auto photo = torch::tensor({2, 0, 1, 2}, torch::kLong);
  EXPECT_TRUE(torch::equal(codes(photo), torch::zeros({4, 2})));  // zero: every photo the mean look
  {
    torch::NoGradGuard no_grad;
    codes->parameter().copy_(torch::tensor({{1.0f, 2.0f}, {4.0f, 2.0f}, {1.0f, -1.0f}}));  // mean (2, 1)
  }
  const auto expected = torch::tensor({{-1.0f, -2.0f}, {-1.0f, 1.0f}, {2.0f, 1.0f}, {-1.0f, -2.0f}});
  EXPECT_TRUE(torch::allclose(codes(photo), expected));
  EXPECT_TRUE(torch::allclose(codes->look(1), expected[2].unsqueeze(0)));
  EXPECT_FALSE(codes->look(1).requires_grad());
  EXPECT_THROW(AppearanceCode(0, 4), std::invalid_argument);
}

TEST(AppearanceCode, EntersTheViewTokenOnly) {
  torch::manual_seed(1);
  AbleNerf model(test::small_le_model_config());
  model->eval();
  const auto rays = test::random_rays(6, 7);
  torch::NoGradGuard no_grad;
  ForwardOptions plain;
  plain.branches = true;
  ForwardOptions zero = plain, coded = plain, per_ray = plain;
  zero.appearance = torch::zeros({1, 16});
  coded.appearance = torch::randn({1, 16});
  per_ray.appearance = coded.appearance.expand({6, 16}).contiguous();
  const auto a = model->forward(rays, 2.0, 6.0, plain), z = model->forward(rays, 2.0, 6.0, zero);
  const auto c = model->forward(rays, 2.0, 6.0, coded), p = model->forward(rays, 2.0, 6.0, per_ray);
  EXPECT_TRUE(torch::allclose(z.rgb_fine, a.rgb_fine, 0, 1e-7));  // a zero code is the mean look
  // The samples, the attention and the ray token's colour never see the code; the LE colour does.
  EXPECT_TRUE(torch::equal(c.fine_t, a.fine_t));
  EXPECT_TRUE(torch::allclose(c.fine_weights, a.fine_weights, 0, 1e-6));
  EXPECT_TRUE(torch::allclose(c.ray_colour_fine, a.ray_colour_fine, 0, 1e-6));
  EXPECT_GT((c.le_colour_fine - a.le_colour_fine).abs().max().item<float>(), 1e-3);
  EXPECT_GT((c.rgb_fine - a.rgb_fine).abs().max().item<float>(), 1e-3);
  // One code for every ray is that code on each ray.
  EXPECT_TRUE(torch::allclose(p.rgb_fine, c.rgb_fine, 0, 1e-6));
}

// Under no gradient the CPU splits the rays across threads (kernels/cpu_parallel.h): each slice
// takes its own rays' codes, so rays with different codes come out as each would alone.
TEST(AppearanceCode, PerRayCodesFollowTheirRaysThroughTheSplit) {
  const test::IntraOpThreads threads(2);
  torch::manual_seed(2);
  AbleNerf model(test::small_le_model_config());
  model->eval();
  const auto rays = test::random_rays(32, 5);
  const auto codes = torch::randn({32, 16});
  torch::NoGradGuard no_grad;
  ForwardOptions all;
  all.appearance = codes;
  const auto together = model->forward(rays, 2.0, 6.0, all).rgb_fine;
  for (const int64_t i : {0, 17, 31}) {
    ForwardOptions one;
    one.appearance = codes.slice(0, i, i + 1);
    const auto alone = model->forward(rays.slice(i, i + 1), 2.0, 6.0, one).rgb_fine;
    EXPECT_TRUE(torch::allclose(alone, together.slice(0, i, i + 1), 0, 1e-5)) << i;
  }
}

TEST(AppearanceCode, GradientReachesTheCodesCentred) {
  torch::manual_seed(3);
  AbleNerf model(test::small_le_model_config());
  model->enable_appearance_code(3);
  const auto rays = test::random_rays(8, 11);
  const auto photo = torch::tensor({0, 0, 1, 1, 0, 1, 0, 1}, torch::kLong);  // photo 2 draws no ray
  ForwardOptions opts;
  opts.appearance = model->appearance_code()->forward(photo);
  model->forward(rays, 2.0, 6.0, opts).rgb_fine.sum().backward();
  const auto g = model->appearance_code()->parameter().grad();
  ASSERT_TRUE(g.defined());
  EXPECT_GT(g[0].abs().max().item<float>(), 0.0f);
  EXPECT_GT(g[2].abs().max().item<float>(), 0.0f);  // through the mean
  // The centred codes' gradient sums to zero over the photos: a common shift changes nothing.
  EXPECT_LT(g.sum(0).abs().max().item<float>(), 1e-5);
}

TEST(AppearanceCode, WeightsCarryTheCodesIntoAModelMadeWithoutThem) {
  test::TempDir dir;
  AbleNerf a(test::small_le_model_config());
  a->enable_appearance_code(4);
  {
    torch::NoGradGuard no_grad;
    a->appearance_code()->parameter().copy_(torch::randn({4, 16}));
  }
  EXPECT_THROW(a->enable_appearance_code(4), std::logic_error);
  save_weights(a, dir / "w.pt");
  AbleNerf b(test::small_le_model_config());
  ASSERT_EQ(b->appearance_code(), nullptr);
  EXPECT_EQ(look_photos(*b), 0);
  load_weights(b, dir / "w.pt");
  ASSERT_NE(b->appearance_code(), nullptr);
  EXPECT_TRUE(torch::equal(b->appearance_code()->parameter(), a->appearance_code()->parameter()));
  // The look of photo 2: its centred code, no colour map; the mean look: neither.
  const PhotoLook l = photo_look(*b, 2, "--look", "");
  EXPECT_EQ(l.colour, nullptr);
  EXPECT_TRUE(torch::allclose(l.appearance, b->appearance_code()->look(2)));
  EXPECT_FALSE(photo_look(*b, -1, "--look", "").appearance.defined());
  EXPECT_THROW(photo_look(*b, 4, "--look", ""), InputError);
  // Codes of another width are refused, naming them.
  ModelConfig wide = test::small_le_model_config();
  wide.width = 32;
  AbleNerf c(wide);
  try {
    load_weights(c, dir / "w.pt");
    FAIL() << "codes of width 16 loaded into a model of width 32";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("appearance_code.codes"), std::string::npos) << e.what();
  }
}

TEST(AppearanceCode, AModelWithoutLearnableEmbeddingsRefusesThem) {
  ModelConfig cfg = test::small_le_model_config();
  cfg.le_count = 0;
  AbleNerf model(cfg);
  EXPECT_THROW(model->enable_appearance_code(3), std::invalid_argument);
  AbleNerf none(test::small_le_model_config());
  EXPECT_THROW(photo_look(*none, 0, "request", "look"), InputError);
}

}  // namespace
}  // namespace ablenerf
