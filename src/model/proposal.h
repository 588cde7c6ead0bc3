#pragma once
// Proposal sampling (model.proposal_samples > 0; docs/MODEL.md, "Proposal sampling"), ablenerf's
// extension for the minutes a real capture gets: the paper spaces the coarse pass's samples evenly
// along each ray and only the fine pass follows attention (section 5). Here a small density field,
// shared by every ray as mip-NeRF 360's proposal MLP (Barron et al. 2022, section 3) and nerfacto's
// proposal grid are, is read at proposal_samples even intervals of the ray; the volume-rendering
// weights of its densities form a histogram from which the coarse fence-posts are drawn (the same
// inverse CDF the paper's resampler uses). The coarse tokens then sit where the scene's surfaces are,
// and the paper's attention resampling places the fine ones among them as before. The field is
// trained only by the proposal loss (train/regularisers.h): its histogram must cover the fine
// pass's attention over the samples; no colour gradient reaches it.
//
// The field: a multiresolution hash grid (model/grid_embedding.h, anti-aliased as the front end's,
// proposal_levels levels up to proposal_max_resolution cells) -> Linear(16) -> ReLU -> Linear(1) ->
// density exp(x), in the sample space of the scene (contracted or NDC as the front end's grid), and
// zero outside the grid's cube.
// Densities count per unit of the normalised ray coordinate s in [0, 1] (model/contraction.h for
// unbounded scenes; (t - near) / (far - near) otherwise), so the field's scale does not depend on
// the scene's units.
#include <torch/torch.h>

#include "model/frustum.h"
#include "model/grid_embedding.h"
#include "model/model_config.h"

namespace ablenerf {

// The field's hidden layer: nerfacto's proposal MLP width (one hidden layer of 16).
constexpr int64_t kProposalHidden = 16;

// Volume-rendering weights of densities sigma (B,N) over intervals with fence-posts s (B,N+1):
// w_i = T_i (1 - exp(-sigma_i (s_i+1 - s_i))), T_i = exp(-sum_j<i sigma_j (s_j+1 - s_j)).
torch::Tensor density_weights(const torch::Tensor& sigma, const torch::Tensor& s);

// The coarse fence-posts (B, samples+1) in s, drawn by inverse CDF from the proposal's weights over
// its fence-posts s (B,N+1), each weight raised by `padding` / N so that a share of the samples stays
// spread along the ray whatever the field says. No gradient. `fused`: as sample_pdf's (model/resampler.h).
torch::Tensor proposal_fence_posts(const torch::Tensor& s, const torch::Tensor& weights, int64_t samples,
                                   double padding, const torch::Tensor& jitter = {}, bool fused = false);

class ProposalImpl : public torch::nn::Module {
 public:
  ProposalImpl(const ModelConfig& cfg, GridCube cube);
  // Densities (B,N) of the interval Gaussians (mean, cov: (B,N,3)).
  torch::Tensor density(const Gaussians& g);
  int64_t samples() const { return samples_; }
  // The field's grid (its table trains with the rest).
  GridEmbeddingImpl& grid() const { return *grid_.ptr(); }

 private:
  int64_t samples_;
  GridEmbedding grid_{nullptr};
  torch::nn::Linear hidden_{nullptr}, out_{nullptr};
};
TORCH_MODULE(Proposal);

}  // namespace ablenerf
