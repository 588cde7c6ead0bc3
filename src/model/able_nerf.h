#pragma once
// The whole ABLE-NeRF forward pass (spec section 7), assembled from one module per stage:
// frustum.h -> ipe.h -> volume_embedding.h -> ab_transformer.h -> resampler.h ->
// le_transformer.h -> tonemap.h.
#include <torch/torch.h>

#include "data/rays.h"
#include "util/config.h"

namespace ablenerf {

// Render-time options for the paper's analyses.
struct ForwardOptions {
  bool branches = false;   // also return the two branch colours before tone mapping
  double le_noise = 0.0;   // std of Gaussian noise added to the LE (0 = none)
  bool le_zero = false;    // zero the LE
  torch::Generator* generator = nullptr;  // for the LE noise / stratified jitter (optional)
};

struct ModelOutput {
  torch::Tensor rgb_coarse, rgb_fine;  // (B,3) sRGB in [0,1]
  torch::Tensor coarse_weights;        // (B,S) last coarse layer's ray-token attention over volumes
  torch::Tensor fine_weights;          // (B,S) last fine layer's ray-token attention over volumes
  torch::Tensor fine_t;                // (B,S+1) fine fence-posts (interval i = [t_i, t_i+1])
  // With ForwardOptions::branches: linear colours before tone mapping.
  torch::Tensor ray_colour_coarse, le_colour_coarse, ray_colour_fine, le_colour_fine;
};

class AbleNerfImpl : public torch::nn::Module {
 public:
  explicit AbleNerfImpl(const ModelConfig& cfg);
  ModelOutput forward(const Rays& rays, double near, double far, const ForwardOptions& opts = {});
  int64_t parameter_count() const;
  const ModelConfig& config() const { return cfg_; }

 private:
  ModelConfig cfg_;
};
TORCH_MODULE(AbleNerf);

}  // namespace ablenerf
