#include "model/volume_embedding.h"

namespace ablenerf {

torch::Tensor linear_tokens(const torch::nn::Linear& layer, const torch::Tensor& x) {
  auto sizes = x.sizes().vec();
  const auto flat = x.reshape({-1, sizes.back()});
  const auto& w = layer->weight;
  auto y = layer->bias.defined() ? torch::addmm(layer->bias, flat, w.t()) : flat.mm(w.t());
  sizes.back() = w.size(0);
  return y.view(sizes);
}

VolumeEmbeddingImpl::VolumeEmbeddingImpl(int64_t in_features, int64_t width) {
  for (int i = 0; i < kLayers; ++i) {
    // torch::nn::Linear's reset() is PyTorch's default init (spec 8.1).
    layers_.push_back(register_module("linear" + std::to_string(i),
                                      torch::nn::Linear(i == 0 ? in_features : width, width)));
  }
}

torch::Tensor VolumeEmbeddingImpl::forward(const torch::Tensor& x) {
  auto h = x;
  for (size_t i = 0; i < layers_.size(); ++i) {
    h = linear_tokens(layers_[i], h);
    if (i + 1 < layers_.size()) h = torch::relu(h);
  }
  return h;
}

}  // namespace ablenerf
