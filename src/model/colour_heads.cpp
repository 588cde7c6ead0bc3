#include "model/colour_heads.h"

#include <cmath>

#include "data/rays.h"
#include "model/linear_tokens.h"

namespace ablenerf {

namespace {
const double kRayColourBias = std::log(3.0);  // sigmoid(-ln 3) = 0.25
constexpr double kLEColourScale = 0.5;        // LE colour lives in (0, 0.5)
}  // namespace

RayColourHeadImpl::RayColourHeadImpl(int64_t width) {
  linear = register_module("linear", torch::nn::Linear(width, kRgbChannels));
}

torch::Tensor RayColourHeadImpl::forward(const torch::Tensor& r) {
  return torch::sigmoid(linear_tokens(linear, r) - kRayColourBias);
}

LEColourHeadImpl::LEColourHeadImpl(int64_t width, int64_t view_width) {
  hidden = register_module("hidden", torch::nn::Linear(width + view_width, width));
  out = register_module("out", torch::nn::Linear(width, kRgbChannels));
}

torch::Tensor LEColourHeadImpl::forward(const torch::Tensor& decoded, const torch::Tensor& view_code) {
  const auto h = linear_relu_tokens(hidden, torch::cat({decoded, view_code}, -1));
  return kLEColourScale * torch::sigmoid(linear_tokens(out, h));
}

}  // namespace ablenerf
