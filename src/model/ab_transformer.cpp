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

torch::Tensor ABTransformerImpl::forward(const torch::Tensor& tokens, const torch::Tensor& mask,
                                         RayQueryProbe* probe) {
  auto x = tokens;
  for (size_t i = 0; i < blocks_.size(); ++i)
    x = blocks_[i]->forward_self(x, mask, i + 1 == blocks_.size() ? probe : nullptr);
  return x;
}

}  // namespace ablenerf
