#include "model/volume_embedding.h"

#include "model/linear_tokens.h"

namespace ablenerf {

VolumeEmbeddingImpl::VolumeEmbeddingImpl(int64_t in_features, int64_t width) {
  for (int i = 0; i < kLayers; ++i) {
    // torch::nn::Linear's reset() is PyTorch's default init (docs/MODEL.md, section 8).
    layers_.push_back(
        register_module("linear" + std::to_string(i), torch::nn::Linear(i == 0 ? in_features : width, width)));
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
