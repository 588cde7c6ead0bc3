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
  // The hidden layers with their ReLU as one node each (model/linear_tokens.h), the last without.
  for (size_t i = 0; i < layers_.size(); ++i)
    h = i + 1 < layers_.size() ? linear_relu_tokens(layers_[i], h) : linear_tokens(layers_[i], h);
  return h;
}

}  // namespace ablenerf
