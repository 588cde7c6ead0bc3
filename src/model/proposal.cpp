#include "model/proposal.h"

#include "kernels/hash_grid.h"
#include "model/linear_tokens.h"
#include "model/resampler.h"
#include "model/model_config.h"

namespace ablenerf {

namespace {
// The density's logit is clamped before exp so that one bad step cannot overflow it (exp(15) is
// far more than any interval needs to be opaque).
constexpr double kMaxLogDensity = 15.0;
}  // namespace

torch::Tensor density_weights(const torch::Tensor& sigma, const torch::Tensor& s) {
  const int64_t n = sigma.size(-1);
  const auto depth = sigma * (s.slice(-1, 1, n + 1) - s.slice(-1, 0, n));  // optical depth per interval
  const auto before = torch::cumsum(depth, -1) - depth;                    // exclusive
  return torch::exp(-before) * (1 - torch::exp(-depth));
}

torch::Tensor proposal_fence_posts(const torch::Tensor& s, const torch::Tensor& weights, int64_t samples,
                                   double padding, const torch::Tensor& jitter, bool fused) {
  torch::NoGradGuard no_grad;
  const auto w = weights.detach().to(torch::kFloat);
  return sample_pdf(s.to(torch::kFloat).contiguous(), w + padding / static_cast<double>(w.size(-1)), samples + 1,
                    jitter, fused)
      .to(s.dtype());
}

ProposalImpl::ProposalImpl(const ModelConfig& cfg, GridCube cube) : samples_(cfg.proposal_samples) {
  // The front end's grid class with the proposal's sizes (features per level and base resolution
  // as the front end's).
  const HashGridShape shape = hash_grid_shape(cfg.proposal_levels, cfg.grid_features, cfg.proposal_log2_table,
                                              cfg.grid_base_resolution, cfg.proposal_max_resolution);
  grid_ = register_module("grid", GridEmbedding(shape, cube, cfg.grid_lr_scale));
  hidden_ = register_module("hidden", torch::nn::Linear(grid_->width(), kProposalHidden));
  out_ = register_module("out", torch::nn::Linear(kProposalHidden, 1));
}

torch::Tensor ProposalImpl::density(const Gaussians& g) {
  torch::Tensor inside;  // whether each mean lies in the grid's cube, 1/0
  const auto features = grid_->forward(g.mean, g.cov, &inside);
  const auto hidden = linear_relu_tokens(hidden_, features.to(hidden_->weight.dtype()));
  const auto logit = linear_tokens(out_, hidden).squeeze(-1);
  // No density outside the grid's cube: there the grid reads zeros and the field would give every
  // point one learned constant, a fog in front of a bounded scene's objects (docs/MODEL.md, "Proposal
  // sampling", item 1).
  return torch::exp(logit.to(torch::kFloat).clamp_max(kMaxLogDensity)) * inside;
}

}  // namespace ablenerf
