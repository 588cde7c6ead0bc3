#pragma once
// Stage 6c (docs/MODEL.md, section 7): the two colour heads of one pass, in linear space.
//  * ray-token head: sigmoid(Linear(R) - ln 3) (Ref-NeRF style bias: initial output ~0.25);
//  * LE head: 0.5 sigmoid(Linear(ReLU(Linear([decoded; e_d])))) in (0, 0.5).
#include <torch/torch.h>

namespace ablenerf {

class RayColourHeadImpl : public torch::nn::Module {
 public:
  explicit RayColourHeadImpl(int64_t width);
  torch::Tensor forward(const torch::Tensor& ray_token);  // (B,E) -> (B,3)
  torch::nn::Linear linear{nullptr};
};
TORCH_MODULE(RayColourHead);

class LEColourHeadImpl : public torch::nn::Module {
 public:
  LEColourHeadImpl(int64_t width, int64_t view_width);
  // decoded: (B,E), view_code: (B,view_width) -> (B,3)
  torch::Tensor forward(const torch::Tensor& decoded, const torch::Tensor& view_code);
  torch::nn::Linear hidden{nullptr}, out{nullptr};
};
TORCH_MODULE(LEColourHead);

}  // namespace ablenerf
