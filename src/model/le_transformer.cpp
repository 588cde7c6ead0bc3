#include "model/le_transformer.h"

namespace ablenerf {

LETransformerImpl::LETransformerImpl(int64_t width, int64_t heads, int64_t ff_width, int64_t le_layers) {
  cross_ = register_module("cross", TransformerBlock(width, heads, ff_width));
  auto list = register_module("self", torch::nn::ModuleList());
  for (int64_t j = 0; j < le_layers; ++j) {
    self_.emplace_back(width, heads, ff_width);
    list->push_back(self_.back());
  }
  decode_ = register_module("decode", TransformerBlock(width, heads, ff_width));
}

torch::Tensor LETransformerImpl::forward(const torch::Tensor& le, const torch::Tensor& volumes,
                                         const torch::Tensor& view) {
  auto x = cross_->forward_cross(le, volumes);  // (B,N,E)
  for (auto& block : self_) x = block->forward_self(x, torch::Tensor());
  return decode_->forward_cross(view.unsqueeze(1), x).squeeze(1);
}

}  // namespace ablenerf
