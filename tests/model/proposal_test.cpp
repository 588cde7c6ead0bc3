// Proposal sampling (model/proposal.h): the volume-rendering weights of a density against their
// closed form, the coarse fence-posts drawn where the weights are (and the padding's even share),
// and the assembled model with model.proposal_samples set (its outputs and where its gradients go).
// The field learning from the proposal loss: tests/train/proposal_training_test.cpp.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>

#include "model/able_nerf.h"
#include "model/proposal.h"
#include "test_util.h"
#include "model/model_config.h"

namespace ablenerf {
namespace {

TEST(Proposal, DensityWeightsMatchTheirClosedForm) {
  // A constant density c over [0, 1]: w_i = exp(-c s_i) - exp(-c s_i+1), summing to 1 - exp(-c).
  const double c = 3.0;
  const auto s = torch::tensor({0.0, 0.1, 0.25, 0.5, 0.8, 1.0}, torch::kDouble).unsqueeze(0);
  const auto w = density_weights(torch::full({1, 5}, c, torch::kDouble), s);
  for (int i = 0; i < 5; ++i)
    EXPECT_NEAR(w[0][i].item<double>(),
                std::exp(-c * s[0][i].item<double>()) - std::exp(-c * s[0][i + 1].item<double>()), 1e-14);
  EXPECT_NEAR(w.sum().item<double>(), 1 - std::exp(-c), 1e-14);
  // An opaque interval hides everything behind it.
  const auto wall = density_weights(torch::tensor({{0.0, 1e4, 2.0, 5.0, 1.0}}, torch::kDouble), s);
  EXPECT_NEAR(wall[0][1].item<double>(), 1.0, 1e-12);
  EXPECT_LT(wall.slice(1, 2).abs().max().item<double>(), 1e-12);
}

TEST(Proposal, FencePostsFollowTheWeightsWithAnEvenShare) {
  const int64_t n = 20, samples = 39;
  const auto s = torch::linspace(0, 1, n + 1, torch::kDouble).unsqueeze(0);
  auto w = torch::zeros({1, n}, torch::kDouble);
  w[0][12] = 1.0;  // all of the field's weight in [0.60, 0.65]
  const auto inside = [&](const torch::Tensor& posts) {
    return ((posts >= 0.6 - 1e-12) & (posts <= 0.65 + 1e-12)).sum().item<int64_t>();
  };
  const auto tight = proposal_fence_posts(s, w, samples, /*padding=*/0.0);
  ASSERT_EQ(tight.size(1), samples + 1);
  EXPECT_EQ(inside(tight), samples + 1);
  // Padding p spreads p / (1 + p) of the posts evenly: 20 bins of 0.2 / 20 each against 1.
  const auto padded = proposal_fence_posts(s, w, samples, 0.2);
  const double even = 0.2 / 1.2 * (samples + 1);
  const int64_t outside = samples + 1 - inside(padded);
  EXPECT_NEAR(static_cast<double>(outside), even * 19.0 / 20.0, 2.0);
  EXPECT_TRUE((padded.slice(1, 1) >= padded.slice(1, 0, samples)).all().item<bool>());
  EXPECT_GE(padded.min().item<double>(), 0.0);
  EXPECT_LE(padded.max().item<double>(), 1.0);
}

TEST(Proposal, TheFieldHasNoDensityOutsideTheGridsCube) {
  // Outside the cube the grid reads zeros, so the field's MLP alone would give every such point one
  // learned constant: a fog in front of a bounded scene's objects. The field is zero there.
  torch::manual_seed(5);
  Proposal field(test::proposal_model_config(), GridCube{-1.5, 1.5});
  // Two rays of three points: inside, on a face, just outside, far outside.
  const auto mean = torch::tensor(
      {{{0.0, 0.2, -0.4}, {1.5, 0.0, 0.0}, {1.51, 0.0, 0.0}}, {{-0.3, 1.49, 0.0}, {0.0, 0.0, -1.6}, {3.0, -3.0, 3.0}}},
      torch::kFloat);
  // The grid's inputs from the fused loop (which also says which points are inside) and from the
  // tensor ops: the same zeros, the same densities.
  torch::Tensor first;
  for (const bool fused : {true, false}) {
    field->grid().set_fused_inputs(fused);
    const auto density = field->density({mean, torch::full({2, 3, 3}, 1e-4, torch::kFloat)});
    ASSERT_EQ(density.sizes(), (std::vector<int64_t>{2, 3}));
    for (const auto& at : {std::pair{0, 0}, std::pair{0, 1}, std::pair{1, 0}})
      EXPECT_GT(density[at.first][at.second].item<double>(), 0.0) << at.first << "," << at.second << " " << fused;
    for (const auto& at : {std::pair{0, 2}, std::pair{1, 1}, std::pair{1, 2}})
      EXPECT_EQ(density[at.first][at.second].item<double>(), 0.0) << at.first << "," << at.second << " " << fused;
    if (!first.defined())
      first = density.detach();
    else
      EXPECT_LT((density - first).abs().max().item<double>(), 1e-5 * first.abs().max().item<double>());
  }
}

TEST(Proposal, TheModelDrawsItsCoarseSamplesFromTheField) {
  torch::manual_seed(2);
  AbleNerf model(test::proposal_model_config());
  ASSERT_NE(model->proposal(), nullptr);
  EXPECT_EQ(model->named_parameters().find("proposal.grid.table") != nullptr, true);
  const Rays rays = test::random_rays(6, 3);
  const auto out = model->forward(rays, 2.0, 6.0);
  ASSERT_TRUE(out.proposal_s.defined() && out.proposal_weights.defined());
  EXPECT_EQ(out.proposal_s.sizes(), (std::vector<int64_t>{6, 25}));
  EXPECT_EQ(out.proposal_weights.sizes(), (std::vector<int64_t>{6, 24}));
  EXPECT_TRUE(out.proposal_weights.requires_grad());
  EXPECT_LE(out.proposal_weights.sum(1).max().item<double>(), 1.0 + 1e-6);
  EXPECT_TRUE((out.fine_t.slice(1, 1) >= out.fine_t.slice(1, 0, 8)).all().item<bool>());
  // The field's weights lead back to the field alone; the colour never reaches the field (the
  // coarse samples are drawn from its weights without gradient).
  out.proposal_weights.sum().backward(/*gradient=*/{}, /*retain_graph=*/true);
  for (const auto& kv : model->named_parameters()) {
    const bool reached = kv.value().grad().defined() && kv.value().grad().abs().max().item<double>() > 0;
    EXPECT_EQ(reached, kv.key().rfind("proposal.", 0) == 0) << kv.key();
  }
  model->zero_grad();
  out.rgb_fine.sum().backward();
  for (const auto& kv : model->named_parameters())
    if (kv.key().rfind("proposal.", 0) == 0)
      EXPECT_TRUE(!kv.value().grad().defined() || kv.value().grad().abs().max().item<double>() == 0) << kv.key();
  // Without the field the paper's even coarse spacing: no proposal outputs.
  ModelConfig paper = test::proposal_model_config();
  paper.proposal_samples = 0;
  AbleNerf plain(paper);
  EXPECT_EQ(plain->proposal(), nullptr);
  EXPECT_FALSE(plain->forward(rays, 2.0, 6.0).proposal_s.defined());
}

}  // namespace
}  // namespace ablenerf
