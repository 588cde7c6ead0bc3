// Stage 6: the direction code, the LE transformer's shared-query path and the colour heads.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>

#include "model/colour_heads.h"
#include "model/le_transformer.h"
#include "model/view_encoding.h"
#include "model/model_config.h"

namespace ablenerf {
namespace {

TEST(ViewEncoding, ReleaseLayoutByHand) {
  const double d[3] = {0.5, -1.0, 2.0};
  const auto e = encode_view(torch::tensor({d[0], d[1], d[2]}, torch::kDouble).view({1, 3}), ViewEncoding::Release)[0];
  ASSERT_EQ(e.size(0), 27);
  EXPECT_EQ(view_encoding_width(ViewEncoding::Release), 27);
  const double f[4] = {1.0, 10.0 / 3.0, 17.0 / 3.0, 8.0};  // linspace(1, 8, 4)
  for (int c = 0; c < 3; ++c) EXPECT_DOUBLE_EQ(e[c].item<double>(), d[c]);
  for (int k = 0; k < 4; ++k)
    for (int c = 0; c < 3; ++c) {
      EXPECT_NEAR(e[3 + 6 * k + c].item<double>(), std::sin(f[k] * d[c]), 1e-12) << k << c;
      EXPECT_NEAR(e[3 + 6 * k + 3 + c].item<double>(), std::cos(f[k] * d[c]), 1e-12) << k << c;
    }
}

TEST(ViewEncoding, PaperOctaves) {
  EXPECT_EQ(view_encoding_width(ViewEncoding::Paper), 99);
  const auto e = encode_view(torch::tensor({0.1, 0.2, 0.3}, torch::kDouble).view({1, 3}), ViewEncoding::Paper)[0];
  ASSERT_EQ(e.size(0), 99);
  EXPECT_NEAR(e[3 + 6 * 15 + 2].item<double>(), std::sin(32768.0 * 0.3), 1e-9);  // top band 2^15
  EXPECT_NEAR(e[3 + 6 * 15 + 5].item<double>(), std::cos(32768.0 * 0.3), 1e-9);
}

TEST(LETransformer, SharedQueriesEqualPerRayQueriesAndRayOrderDoesNotMix) {
  torch::manual_seed(21);
  const int64_t e = 64, b = 3;
  LETransformer lt(e, 2, 128, 2);
  const auto le = torch::randn({1, 8, e});
  const auto vol = torch::randn({b, 10, e});
  const auto view = torch::randn({b, e});
  const auto out = lt->forward(le, vol, view);
  ASSERT_EQ(out.sizes(), (std::vector<int64_t>{b, e}));
  const auto expanded = lt->forward(le.expand({b, 8, e}), vol, view);
  EXPECT_TRUE(torch::allclose(out, expanded, 1e-5, 1e-5));
  // Each ray's output depends only on its own volumes and view token.
  const auto single = lt->forward(le, vol.slice(0, 2, 3), view.slice(0, 2, 3));
  EXPECT_TRUE(torch::allclose(out.slice(0, 2, 3), single, 1e-5, 1e-5));
  // The volumes matter (cross-attention) and the view token matters (decode query).
  EXPECT_FALSE(torch::allclose(out, lt->forward(le, vol.flip(1) + 0.5, view), 1e-3, 1e-3));
  EXPECT_FALSE(torch::allclose(out, lt->forward(le, vol, -view), 1e-3, 1e-3));
}

TEST(ColourHeads, ClosedForms) {
  torch::manual_seed(22);
  RayColourHead ray(16);
  {
    torch::NoGradGuard g;
    ray->linear->weight.zero_();
    ray->linear->bias.zero_();
  }
  // sigmoid(-ln 3) = 1/(1+3) = 0.25.
  EXPECT_TRUE(torch::allclose(ray->forward(torch::randn({2, 16})), torch::full({2, 3}, 0.25f)));
  LEColourHead le(16, 27);
  EXPECT_EQ(le->hidden->weight.size(1), 16 + 27);
  const auto c = le->forward(torch::randn({4, 16}) * 100, torch::randn({4, 27}) * 100);
  EXPECT_GE(c.min().item<double>(), 0.0);
  EXPECT_LE(c.max().item<double>(), 0.5);
}

}  // namespace
}  // namespace ablenerf
