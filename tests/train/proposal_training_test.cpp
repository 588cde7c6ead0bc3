// The proposal field (model/proposal.h) trained by mip-NeRF 360's proposal loss alone
// (train/regularisers.h): it learns where a target's weight lies, and the coarse fence-posts drawn
// from it then gather there.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include "model/proposal.h"
#include "test_util.h"
#include "train/regularisers.h"
#include "model/model_config.h"

namespace ablenerf {
namespace {

TEST(Proposal, LearnsATargetFromTheProposalLossAndSamplesThere) {
  // Rays through the box along +z (bounded scene, near 0, far 2.4 from z = -1.2). The target puts
  // every ray's weight in s in [0.60, 0.65] (a wall at z ~ 0.3): the proposal loss alone must teach
  // the field that, and the coarse fence-posts drawn from it must then gather there.
  torch::manual_seed(5);
  const ModelConfig cfg = test::proposal_model_config();
  Proposal proposal(cfg, GridCube{-1.5, 1.5});
  const int64_t b = 64, n = cfg.proposal_samples, m = 20;
  auto gen = at::detail::createCPUGenerator(9);
  const auto xy = torch::rand({b, 2}, gen) * 1.6 - 0.8;
  const Rays rays{torch::cat({xy, torch::full({b, 1}, -1.2)}, 1),
                  torch::tensor({0.0f, 0.0f, 1.0f}).expand({b, 3}).contiguous(), torch::full({b, 1}, 1e-3f)};
  const double near = 0.0, far = 2.4;
  const auto s_p = torch::linspace(0, 1, n + 1).unsqueeze(0).expand({b, n + 1});
  const Gaussians g = cast_intervals(near + (far - near) * s_p, rays);
  const auto s_t = torch::linspace(0, 1, m + 1).unsqueeze(0).expand({b, m + 1});
  auto w_t = torch::zeros({b, m});
  w_t.select(1, 12).fill_(1.0);
  torch::optim::Adam adam(proposal->parameters(), torch::optim::AdamOptions(1e-2));
  double first = 0, last = 0;
  for (int step = 0; step < 300; ++step) {
    adam.zero_grad();
    const auto loss = proposal_loss(s_p, density_weights(proposal->density(g), s_p), s_t, w_t).mean();
    loss.backward();
    adam.step();
    (step == 0 ? first : last) = loss.item<double>();
  }
  EXPECT_GT(first, 0.5);  // the untrained field covers little of the target
  EXPECT_LT(last, 0.05 * first);
  torch::NoGradGuard no_grad;
  const auto w = density_weights(proposal->density(g), s_p);
  const auto posts = proposal_fence_posts(s_p, w, cfg.samples, 0.0);
  // Proposal intervals are 1/24 wide: the wall's interval [0.60, 0.65] is covered by those in
  // [0.583, 0.667]; nearly all posts lie there.
  const double share = ((posts >= 0.58) & (posts <= 0.67)).to(torch::kDouble).mean().item<double>();
  EXPECT_GT(share, 0.8);
}

}  // namespace
}  // namespace ablenerf
