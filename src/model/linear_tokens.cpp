#include "model/linear_tokens.h"

namespace ablenerf {

torch::Tensor linear_tokens(const torch::nn::Linear& layer, const torch::Tensor& x, bool with_bias) {
  auto sizes = x.sizes().vec();
  const auto flat = x.reshape({-1, sizes.back()});
  const auto& w = layer->weight;
  auto y = with_bias && layer->bias.defined() ? torch::addmm(layer->bias, flat, w.t()) : flat.mm(w.t());
  sizes.back() = w.size(0);
  return y.view(sizes);
}

}  // namespace ablenerf
