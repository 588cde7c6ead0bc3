#pragma once
// Stage 6b (docs/MODEL.md, section 6): the LE transformer of one pass. The learnable embeddings cross-attend to
// the pass's volume tokens (ray token excluded), refine themselves with `le_layers` self-
// attention blocks, and are decoded by the view token as the single query.
#include <torch/torch.h>

#include "model/attention.h"

namespace ablenerf {

class LETransformerImpl : public torch::nn::Module {
 public:
  LETransformerImpl(int64_t width, int64_t heads, int64_t ff_width, int64_t le_layers);
  // le: (1,N,E) shared embeddings (its query projection is computed once, not per ray);
  // volumes: (B,S,E); view: (B,E). Returns the decoded vector (B,E).
  torch::Tensor forward(const torch::Tensor& le, const torch::Tensor& volumes, const torch::Tensor& view);

 private:
  TransformerBlock cross_{nullptr}, decode_{nullptr};
  std::vector<TransformerBlock> self_;
};
TORCH_MODULE(LETransformer);

}  // namespace ablenerf
