// The loss terms beside the colour loss (train/regularisers.h): mip-NeRF 360's distortion loss
// against its double sum written out and its closed forms, with gradients checked by finite
// differences; Zip-NeRF's normalised weight decay against its closed form; and both wired into a
// training step: the attention weights carry a gradient only when the distortion loss asks for it,
// and the step's gradients are the colour loss's plus exactly these terms'; the step reports each
// term, and the proposal loss taken the other way round reaches only the attention.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <map>
#include <string>

#include "test_util.h"
#include "train_fixture.h"
#include "train/grad_accumulation.h"
#include "train/regularisers.h"
#include "train/train_config.h"
#include "model/model_config.h"

namespace ablenerf {
namespace {

// The definition, O(S^2): sum_ij w_i w_j |m_i - m_j| + 1/3 sum_i w_i^2 (s_i+1 - s_i).
double distortion_double_sum(const torch::Tensor& w, const torch::Tensor& s) {
  const auto wa = w.accessor<double, 1>();
  const auto sa = s.accessor<double, 1>();
  double total = 0;
  for (int64_t i = 0; i < w.size(0); ++i) {
    const double mi = 0.5 * (sa[i] + sa[i + 1]);
    for (int64_t j = 0; j < w.size(0); ++j) total += wa[i] * wa[j] * std::abs(mi - 0.5 * (sa[j] + sa[j + 1]));
    total += wa[i] * wa[i] * (sa[i + 1] - sa[i]) / 3;
  }
  return total;
}

// Sorted fence-posts in [0, 1] with uneven gaps, and weights summing to at most 1.
std::pair<torch::Tensor, torch::Tensor> random_rays_weights(int64_t b, int64_t s, uint64_t seed) {
  auto gen = at::detail::createCPUGenerator(seed);
  auto posts = std::get<0>(torch::rand({b, s + 1}, gen, torch::kDouble).sort(1));
  posts = (posts - posts.select(1, 0).unsqueeze(1)) / (posts.select(1, s) - posts.select(1, 0)).unsqueeze(1);
  auto w = torch::rand({b, s}, gen, torch::kDouble);
  w = w / w.sum(1, true) * 0.9;
  return {w, posts};
}

ModelConfig regulariser_model(bool grid) {
  if (!grid) return test::two_head_model();
  ModelConfig m = test::two_head_grid_model(3, 6, 2, 8, ModelConfig{}.grid_bound);
  m.grid_lr_scale = 3;
  return m;
}

// One training step's gradients by parameter name (zeros where a parameter has none), its loss and
// its reported terms, which must add up to the loss, the fine one being the fine MSE (fine_weight 1).
std::map<std::string, torch::Tensor> step_gradients(AbleNerf& model, const RayBatch& batch, int64_t micro,
                                                    const TrainConfig& tc, int64_t global, double* loss,
                                                    torch::Tensor* terms, const torch::Tensor& distortion_scale = {}) {
  for (auto& p : model->parameters()) p.mutable_grad() = torch::Tensor();
  const StepSums sums = accumulate_gradients(model, batch, micro, tc, global, 2.0, 6.0, distortion_scale);
  *loss = sums.loss.item<double>();
  *terms = sums.terms.to(torch::kDouble);
  EXPECT_NEAR(terms->sum().item<double>(), *loss, 1e-6 * *loss);
  EXPECT_NEAR((*terms)[kTermFine].item<double>(), sums.mse_fine.item<double>(), 1e-6 * *loss);
  std::map<std::string, torch::Tensor> g;
  for (const auto& kv : model->named_parameters())
    g[kv.key()] = kv.value().grad().defined() ? kv.value().grad().clone() : torch::zeros_like(kv.value());
  return g;
}

TEST(Regularisers, DistortionEqualsItsDoubleSum) {
  const auto [w, s] = random_rays_weights(6, 11, 3);
  const auto fast = distortion_loss(w, s);
  ASSERT_EQ(fast.sizes(), (std::vector<int64_t>{6}));
  for (int64_t r = 0; r < 6; ++r)
    EXPECT_NEAR(fast[r].item<double>(), distortion_double_sum(w[r], s[r]), 1e-13) << "ray " << r;
}

TEST(Regularisers, DistortionClosedForms) {
  const auto s = torch::tensor({0.0, 0.1, 0.4, 0.5, 0.9, 1.0}, torch::kDouble).unsqueeze(0);
  // All the weight in one interval: only its own term, w^2 (width) / 3.
  const auto one = torch::tensor({0.0, 0.0, 0.8, 0.0, 0.0}, torch::kDouble).unsqueeze(0);
  EXPECT_NEAR(distortion_loss(one, s).item<double>(), 0.64 * 0.1 / 3, 1e-15);
  // Two intervals: 2 w1 w2 |m1 - m2| plus their own terms.
  const auto two = torch::tensor({0.5, 0.0, 0.0, 0.0, 0.25}, torch::kDouble).unsqueeze(0);
  const double expected = 2 * 0.5 * 0.25 * (0.95 - 0.05) + (0.25 * 0.1 + 0.0625 * 0.1) / 3;
  EXPECT_NEAR(distortion_loss(two, s).item<double>(), expected, 1e-15);
  // Spreading the same weight over the ray costs more than one compact interval.
  const auto spread = torch::full({1, 5}, 0.8 / 5, torch::kDouble);
  EXPECT_GT(distortion_loss(spread, s).item<double>(), distortion_loss(one, s).item<double>());
}

TEST(Regularisers, DistortionGradientMatchesFiniteDifferences) {
  auto [w, s] = random_rays_weights(2, 7, 5);
  w.requires_grad_(true);
  distortion_loss(w, s).sum().backward();
  const double h = 1e-6;
  for (int64_t r = 0; r < 2; ++r) {
    for (int64_t i = 0; i < 7; ++i) {
      auto up = w.detach().clone(), down = w.detach().clone();
      up[r][i] += h;
      down[r][i] -= h;
      const double fd = (distortion_double_sum(up[r], s[r]) - distortion_double_sum(down[r], s[r])) / (2 * h);
      EXPECT_NEAR(w.grad()[r][i].item<double>(), fd, 1e-7) << "ray " << r << " interval " << i;
    }
  }
}

TEST(Regularisers, AttentionDistributionSumsToOneAndKeepsTheShape) {
  const auto [w, s] = random_rays_weights(4, 9, 11);
  const auto p = attention_distribution(w * 0.3);  // 70% more on the ray token: same distribution
  EXPECT_TRUE(torch::allclose(p.sum(1), torch::ones({4}, torch::kDouble), 0, 1e-14));
  EXPECT_TRUE(torch::allclose(p, attention_distribution(w), 0, 1e-14));
  // So the distortion of the distribution cannot be lowered by attending to the ray token.
  EXPECT_NEAR(distortion_loss(attention_distribution(w * 0.1), s).sum().item<double>(),
              distortion_loss(attention_distribution(w), s).sum().item<double>(), 1e-12);
}

TEST(Regularisers, ProposalLossIsZeroWhereTheProposalCoversTheTarget) {
  const auto s = torch::tensor({{0.0, 0.2, 0.4, 0.6, 0.8, 1.0}}, torch::kDouble);
  const auto w = torch::tensor({{0.1, 0.5, 0.2, 0.1, 0.1}}, torch::kDouble);
  // The same histogram bounds itself.
  EXPECT_NEAR(proposal_loss(s, w, s, w).item<double>(), 0.0, 1e-15);
  // One proposal interval over the target's whole support bounds any split of it.
  const auto wide = torch::tensor({{0.0, 0.3, 0.7, 1.0}}, torch::kDouble);
  const auto fine = torch::tensor({{0.0, 0.35, 0.4, 0.5, 0.65, 1.0}}, torch::kDouble);
  EXPECT_NEAR(proposal_loss(wide, torch::tensor({{0.0, 0.9, 0.0}}, torch::kDouble), fine,
                            torch::tensor({{0.0, 0.3, 0.3, 0.3, 0.0}}, torch::kDouble))
                  .item<double>(),
              0.0, 1e-15);
}

TEST(Regularisers, ProposalLossByHand) {
  // Proposal posts 0, .5, 1 with weights .2, .3; target posts 0, .2, .45, .7, 1 with .1, .4, .3, .2.
  // Target intervals [0, .2] and [.2, .45] lie in proposal interval 0 (bound .2), [.45, .7] straddles
  // both (bound .5), [.7, 1] lies in interval 1 (bound .3): only [.2, .45] exceeds its bound, by .2.
  const auto sp = torch::tensor({{0.0, 0.5, 1.0}}, torch::kDouble);
  const auto wp = torch::tensor({{0.2, 0.3}}, torch::kDouble);
  const auto st = torch::tensor({{0.0, 0.2, 0.45, 0.7, 1.0}}, torch::kDouble);
  const auto wt = torch::tensor({{0.1, 0.4, 0.3, 0.2}}, torch::kDouble);
  const double eps = 1e-7;
  const double expected = 0.2 * 0.2 / (0.4 + eps);
  EXPECT_NEAR(proposal_loss(sp, wp, st, wt).item<double>(), expected, 1e-14);
  // A target interval straddling a proposal post sees both intervals: [.4, .6] is bounded by .5.
  const auto st2 = torch::tensor({{0.0, 0.4, 0.6, 1.0}}, torch::kDouble);
  const auto wt2 = torch::tensor({{0.0, 0.6, 0.0}}, torch::kDouble);
  EXPECT_NEAR(proposal_loss(sp, wp, st2, wt2).item<double>(), 0.1 * 0.1 / (0.6 + eps), 1e-14);
}

TEST(Regularisers, ProposalLossGradientMatchesFiniteDifferences) {
  torch::manual_seed(8);
  const auto sp = std::get<0>(torch::rand({3, 9}, torch::kDouble).sort(1));
  const auto st = std::get<0>(torch::rand({3, 13}, torch::kDouble).sort(1));
  const auto wt = torch::rand({3, 12}, torch::kDouble) * 0.3;
  auto wp = (torch::rand({3, 8}, torch::kDouble) * 0.3).requires_grad_(true);
  proposal_loss(sp, wp, st, wt).sum().backward();
  const double h = 1e-6;
  for (int r = 0; r < 3; ++r)
    for (int j = 0; j < 8; ++j) {
      auto up = wp.detach().clone(), down = wp.detach().clone();
      up[r][j] += h;
      down[r][j] -= h;
      const double fd =
          (proposal_loss(sp, up, st, wt).sum().item<double>() - proposal_loss(sp, down, st, wt).sum().item<double>()) /
          (2 * h);
      EXPECT_NEAR(wp.grad()[r][j].item<double>(), fd, 1e-6) << r << "," << j;
    }
  EXPECT_GT(wp.grad().abs().max().item<double>(), 0.0);
}

TEST(Regularisers, GridDecayIsTheSumOfLevelMeans) {
  // Level l holds +-c_l: its mean square is c_l^2 whatever the signs.
  auto table = torch::ones({3, 16, 2}, torch::kDouble);
  table[0] *= 0.5;
  table[1] *= -2.0;
  table[2].slice(0, 0, 8) *= -3.0;
  table[2].slice(0, 8) *= 3.0;
  EXPECT_NEAR(grid_weight_decay(table).item<double>(), 0.25 + 4.0 + 9.0, 1e-14);
}

TEST(Regularisers, FusedGridDecayEqualsAutogradOnTheScaledTable) {
  // add_grid_weight_decay(param, scale, weight) is grid_weight_decay(scale * param) * weight, its
  // gradient added to whatever param.grad holds.
  torch::manual_seed(11);
  const double scale = 5.0, weight = 0.35;
  auto ref = torch::randn({4, 32, 3}, torch::kDouble).requires_grad_(true);
  (grid_weight_decay(ref * scale) * weight).backward();
  const auto expected_grad = ref.grad().clone();
  const double expected = (grid_weight_decay(ref.detach() * scale) * weight).item<double>();
  // Closed form too: the sum over levels of mean squares is sum(p^2) / (rows * features) here.
  EXPECT_NEAR(expected, weight * scale * scale * ref.detach().pow(2).sum().item<double>() / (32 * 3), 1e-12);

  const auto param = ref.detach().clone().requires_grad_(true);
  EXPECT_NEAR(add_grid_weight_decay(param, scale, weight).item<double>(), expected, 1e-12 * expected);
  ASSERT_TRUE(param.grad().defined());
  EXPECT_TRUE(torch::allclose(param.grad(), expected_grad, 0, 1e-13));
  // A gradient already there (the colour loss's) is added to, not replaced.
  const auto before = torch::randn_like(param);
  param.mutable_grad() = before.clone();
  add_grid_weight_decay(param, scale, weight);
  EXPECT_TRUE(torch::allclose(param.grad(), before + expected_grad, 0, 1e-13));
  EXPECT_FALSE(add_grid_weight_decay(param, scale, weight).requires_grad());
}

TEST(Regularisers, AttentionWeightsCarryAGradientOnlyWhenAsked) {
  torch::manual_seed(3);
  AbleNerf model(regulariser_model(false));
  model->to(torch::kDouble);
  model->eval();
  const Rays rays = test::random_rays(10, 4, torch::kDouble);
  const auto plain = model->forward(rays, 2.0, 6.0);
  EXPECT_FALSE(plain.fine_weights.requires_grad());
  ForwardOptions o;
  o.weights_grad = true;
  const auto kept = model->forward(rays, 2.0, 6.0, o);
  ASSERT_TRUE(kept.fine_weights.requires_grad());
  // Same values either way, and the normalised fence-posts span [0, 1] as the depths span [near, far].
  EXPECT_TRUE(torch::allclose(kept.fine_weights, plain.fine_weights, 0, 1e-14));
  EXPECT_TRUE(torch::allclose(kept.fine_s, (kept.fine_t - 2.0) / 4.0, 0, 1e-14));
  // The loss on the fine attention reaches the coarse pass too (the fine ray token is the coarse one).
  distortion_loss(kept.fine_weights, kept.fine_s).sum().backward();
  const auto& tokens = model->named_parameters()["coarse.blocks.0.attn.in_proj_weight"];
  ASSERT_TRUE(tokens.grad().defined());
  EXPECT_GT(tokens.grad().abs().max().item<double>(), 0);
}

TEST(Regularisers, StepGradientsAreTheColourLossPlusTheTerms) {
  torch::manual_seed(6);
  AbleNerf model(regulariser_model(true));
  model->eval();  // float32 (the table's kernels are); no jitter: both steps see the same samples
  {
    // A trained table's size, not the initial 1e-4: the decay's gradient must show above rounding.
    torch::NoGradGuard no_grad;
    model->named_parameters()["grid.table"].uniform_(-0.2, 0.2);
  }
  auto gen = at::detail::createCPUGenerator(7);
  const int64_t n = 12, global = 36;  // this process's share of a 36-ray step
  const RayBatch batch{test::random_rays(n, 8, torch::kFloat), torch::rand({n, 3}, gen, torch::kFloat),
                       torch::Tensor()};
  torch::Tensor reported;  // the last step's terms (StepSums::terms)
  const auto grads_of = [&](const TrainConfig& tc, double* loss) {
    return step_gradients(model, batch, 5, tc, global, loss, &reported);
  };
  TrainConfig colour;
  TrainConfig both = colour;
  both.distortion_weight = 0.3;
  both.grid_decay = 0.7;
  double colour_loss = 0, both_loss = 0;
  const auto g0 = grads_of(colour, &colour_loss);
  const auto g1 = grads_of(both, &both_loss);

  // The terms written out with plain autograd: distortion over the whole batch, the decay scaled by
  // this process's share of the step.
  for (auto& p : model->parameters()) p.mutable_grad() = torch::Tensor();
  ForwardOptions o;
  o.weights_grad = true;
  const auto out = model->forward(batch.rays, 2.0, 6.0, o);
  const auto distortion = distortion_loss(attention_distribution(out.fine_weights), out.fine_s).sum() * (0.3 / global);
  // The decay over the entries a lookup reaches (the step leaves a dense level's unused rows alone).
  const auto decay =
      grid_weight_decay(model->grid()->table() * test::table_entries_mask(*model->grid())) * (0.7 * n / global);
  const auto terms = distortion + decay;
  terms.backward();
  EXPECT_NEAR(both_loss, colour_loss + terms.item<double>(), 1e-6 * both_loss);
  // Each term is reported under its own name, and no term that is off shows.
  EXPECT_NEAR(reported[kTermDistortion].item<double>(), distortion.item<double>(), 1e-5 * distortion.item<double>());
  EXPECT_NEAR(reported[kTermGridDecay].item<double>(), decay.item<double>(), 1e-5 * decay.item<double>());
  EXPECT_GT(reported[kTermCoarse].item<double>(), 0);
  for (const LossTerm off : {kTermProposal, kTermPhotoColourDecay, kTermAppearanceDecay, kTermCameraRefineDecay})
    EXPECT_EQ(reported[off].item<double>(), 0) << kLossTermNames[off];
  // The step's gradient less the colour loss's is the terms' gradient, to float rounding.
  for (const auto& kv : model->named_parameters()) {
    const auto term = kv.value().grad().defined() ? kv.value().grad() : torch::zeros_like(kv.value());
    const double tol = 1e-3 * term.abs().max().item<double>() + 1e-6 * (1 + g0.at(kv.key()).abs().max().item<double>());
    EXPECT_LT((g1.at(kv.key()) - g0.at(kv.key()) - term).abs().max().item<double>(), tol) << kv.key();
  }
  // Both terms matter: the decay on the table, the distortion on the transformer's weights.
  EXPECT_GT(model->named_parameters()["grid.table"].grad().abs().max().item<double>(), 1e-3);
  EXPECT_GT(model->named_parameters()["fine.blocks.1.attn.in_proj_weight"].grad().abs().max().item<double>(), 1e-5);
}

TEST(Regularisers, DistortionRampFollowsTheSchedule) {
  // train.distortion_start: off on the whole schedule's first part, then a linear rise over
  // kDistortionRamp of it; no start means the full weight from the first step.
  for (const double f : {0.0, 0.3, 1.0}) EXPECT_EQ(distortion_ramp(0.0, f), 1.0);
  EXPECT_EQ(distortion_ramp(0.5, 0.0), 0.0);
  EXPECT_EQ(distortion_ramp(0.5, 0.5), 0.0);
  EXPECT_NEAR(distortion_ramp(0.5, 0.5 + 0.25 * kDistortionRamp), 0.25, 1e-12);
  EXPECT_NEAR(distortion_ramp(0.5, 0.5 + 0.75 * kDistortionRamp), 0.75, 1e-12);
  EXPECT_NEAR(distortion_ramp(0.5, 0.5 + kDistortionRamp), 1.0, 1e-12);
  EXPECT_EQ(distortion_ramp(0.5, 0.5 + 2 * kDistortionRamp), 1.0);
  // Begun late, the rise is cut off where the schedule ends.
  EXPECT_NEAR(distortion_ramp(0.95, 1.0), 0.05 / kDistortionRamp, 1e-12);
  // train.distortion_ramp: a longer rise, or none.
  EXPECT_NEAR(distortion_ramp(0.5, 0.6, 0.4), 0.25, 1e-12);
  EXPECT_NEAR(distortion_ramp(0.5, 0.9, 0.4), 1.0, 1e-12);
  EXPECT_EQ(distortion_ramp(0.5, 0.4999, 0.0), 0.0);
  EXPECT_EQ(distortion_ramp(0.5, 0.5, 0.0), 1.0);
}

TEST(Regularisers, DistortionScaleScalesOnlyTheDistortionTerm) {
  // The ramp's share enters as a 0-d tensor: the step's gradient with share a is the colour loss's
  // plus a times the full term's, and the reported term is a times the full one.
  torch::manual_seed(16);
  AbleNerf model(regulariser_model(false));
  model->eval();
  auto gen = at::detail::createCPUGenerator(17);
  const int64_t n = 10, global = 20;
  const RayBatch batch{test::random_rays(n, 18, torch::kFloat), torch::rand({n, 3}, gen, torch::kFloat),
                       torch::Tensor()};
  TrainConfig colour;
  TrainConfig with = colour;
  with.distortion_weight = 0.4;
  double l0 = 0, l1 = 0, la = 0;
  torch::Tensor t0, t1, ta;
  const auto g0 = step_gradients(model, batch, 5, colour, global, &l0, &t0);
  const auto g1 = step_gradients(model, batch, 5, with, global, &l1, &t1);
  const auto ga = step_gradients(model, batch, 5, with, global, &la, &ta, torch::full({}, 0.25, torch::kFloat));
  ASSERT_GT(t1[kTermDistortion].item<double>(), 0);
  EXPECT_NEAR(ta[kTermDistortion].item<double>(), 0.25 * t1[kTermDistortion].item<double>(),
              1e-6 * t1[kTermDistortion].item<double>());
  EXPECT_NEAR(la, l0 + 0.25 * (l1 - l0), 1e-6 * l1);
  for (const auto& kv : g0) {
    const auto want = kv.second + 0.25 * (g1.at(kv.first) - kv.second);
    const double tol = 1e-5 * (1 + g1.at(kv.first).abs().max().item<double>());
    EXPECT_LT((ga.at(kv.first) - want).abs().max().item<double>(), tol) << kv.first;
  }
  // A share of 0 leaves the colour loss's gradient.
  double lz = 0;
  torch::Tensor tz;
  const auto gz = step_gradients(model, batch, 5, with, global, &lz, &tz, torch::zeros({}, torch::kFloat));
  EXPECT_EQ(tz[kTermDistortion].item<double>(), 0);
  for (const auto& kv : g0)
    EXPECT_LT((gz.at(kv.first) - kv.second).abs().max().item<double>(),
              1e-6 * (1 + kv.second.abs().max().item<double>()))
        << kv.first;
}

TEST(Regularisers, ProposalAttentionTermMovesOnlyTheAttention) {
  // train.proposal_attention_weight: the proposal loss with the field held constant, on the fine
  // attention. The step's gradients less those without it are exactly that loss's gradient written
  // out with plain autograd; none of it reaches the proposal field, and it does reach the transformer.
  torch::manual_seed(11);
  AbleNerf model(test::proposal_model_config());
  model->eval();  // no jitter: every forward sees the same samples
  auto gen = at::detail::createCPUGenerator(12);
  const int64_t n = 16, global = 32;
  const RayBatch batch{test::random_rays(n, 13, torch::kFloat), torch::rand({n, 3}, gen, torch::kFloat),
                       torch::Tensor()};
  torch::Tensor reported;
  double loss = 0;
  const auto grads_of = [&](const TrainConfig& tc) {
    return step_gradients(model, batch, 8, tc, global, &loss, &reported);
  };
  TrainConfig plain;
  TrainConfig pulled = plain;
  pulled.proposal_attention_weight = 0.5;
  const auto g0 = grads_of(plain);
  EXPECT_EQ(reported[kTermProposalAttention].item<double>(), 0);
  const auto g1 = grads_of(pulled);

  for (auto& p : model->parameters()) p.mutable_grad() = torch::Tensor();
  ForwardOptions o;
  o.weights_grad = true;
  const auto out = model->forward(batch.rays, 2.0, 6.0, o);
  const auto term =
      proposal_loss(out.proposal_s, out.proposal_weights.detach(), out.fine_s, attention_distribution(out.fine_weights))
          .sum() *
      (0.5 / global);
  ASSERT_GT(term.item<double>(), 1e-6);  // the untrained field leaves attention uncovered
  term.backward();
  EXPECT_NEAR(reported[kTermProposalAttention].item<double>(), term.item<double>(), 1e-5 * term.item<double>());
  double reached = 0;
  for (const auto& kv : model->named_parameters()) {
    const auto diff = g1.at(kv.key()) - g0.at(kv.key());
    if (kv.key().rfind("proposal.", 0) == 0) {
      EXPECT_EQ(diff.abs().max().item<double>(), 0) << kv.key();
      continue;
    }
    const auto ref = kv.value().grad().defined() ? kv.value().grad() : torch::zeros_like(kv.value());
    const double tol = 1e-3 * ref.abs().max().item<double>() + 1e-6 * (1 + g0.at(kv.key()).abs().max().item<double>());
    EXPECT_LT((diff - ref).abs().max().item<double>(), tol) << kv.key();
    reached = std::max(reached, ref.abs().max().item<double>());
  }
  EXPECT_GT(reached, 1e-6);
}

}  // namespace
}  // namespace ablenerf
