#pragma once
// Stage 3 (docs/MODEL.md, section 3): the volume-embedding MLP, shared by the coarse and fine passes:
// in -> width -> width -> width -> width, ReLU between layers, none after the last.
#include <torch/torch.h>

namespace ablenerf {

class VolumeEmbeddingImpl : public torch::nn::Module {
 public:
  static constexpr int kLayers = 4;
  VolumeEmbeddingImpl(int64_t in_features, int64_t width);
  torch::Tensor forward(const torch::Tensor& x);

 private:
  std::vector<torch::nn::Linear> layers_;
};
TORCH_MODULE(VolumeEmbedding);

}  // namespace ablenerf
