#include "model/ab_transformer.h"

#include <limits>

namespace ablenerf {

torch::Tensor ray_attention_mask(int64_t samples, const torch::TensorOptions& options) {
  const int64_t n = samples + 1;
  // Strict upper triangle = key farther than query; row 0 (the ray token) is exempt.
  auto blocked = torch::ones({n, n}, options.dtype(torch::kBool)).triu(1);
  blocked[0].fill_(false);
  return torch::zeros({n, n}, options).masked_fill(blocked, -std::numeric_limits<double>::infinity());
}

ABTransformerImpl::ABTransformerImpl(int64_t width, int64_t heads, int64_t ff_width, int64_t layers) {
  auto list = register_module("blocks", torch::nn::ModuleList());
  for (int64_t i = 0; i < layers; ++i) {
    blocks_.emplace_back(width, heads, ff_width);
    list->push_back(blocks_.back());
  }
}

torch::Tensor ABTransformerImpl::forward(const torch::Tensor& tokens, const torch::Tensor& mask, RayQueryProbe* probe,
                                         bool ray_token_only) {
  auto x = tokens;
  for (size_t i = 0; i < blocks_.size(); ++i) {
    const bool last = i + 1 == blocks_.size();
    // The ray token's row of the mask blocks nothing, so its row alone is plain cross-attention.
    x = last && ray_token_only ? blocks_[i]->forward_first(x, probe)
                               : blocks_[i]->forward_self(x, mask, last ? probe : nullptr);
  }
  if (ray_token_only && blocks_.empty()) x = x.slice(1, 0, 1);
  return x;
}

}  // namespace ablenerf
