#pragma once
// Stage 4b (docs/MODEL.md, section 4): the AB (attention-based rendering) transformer: a stack of post-norm
// blocks over [ray token; volume tokens in increasing t], with the causal volume mask below.
#include <torch/torch.h>

#include "model/attention.h"

namespace ablenerf {

// The additive (S+1,S+1) mask of docs/MODEL.md, section 4: row 0 (ray token) sees every column; row i >= 1
// (volume i) sees columns 0..i (the ray token and the volumes not farther than itself).
// 0 where attention is allowed, -inf where it is blocked. Built once per model and broadcast
// over rays and heads.
torch::Tensor ray_attention_mask(int64_t samples, const torch::TensorOptions& options = {});

class ABTransformerImpl : public torch::nn::Module {
 public:
  ABTransformerImpl(int64_t width, int64_t heads, int64_t ff_width, int64_t layers);
  // tokens: (B,S+1,E); mask: ray_attention_mask(S) or undefined (bidirectional ablation).
  // `probe` receives the last layer's ray-token query and keys. With `ray_token_only` the result
  // is only the ray token, (B,1,E): the last layer then computes that row alone.
  torch::Tensor forward(const torch::Tensor& tokens, const torch::Tensor& mask, RayQueryProbe* probe = nullptr,
                        bool ray_token_only = false);
  TransformerBlock& block(int64_t i) { return blocks_.at(static_cast<size_t>(i)); }

 private:
  std::vector<TransformerBlock> blocks_;
};
TORCH_MODULE(ABTransformer);

}  // namespace ablenerf
