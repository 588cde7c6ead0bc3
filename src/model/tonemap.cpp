#include "model/tonemap.h"

namespace ablenerf {

torch::Tensor linear_to_srgb(const torch::Tensor& x) {
  const auto low = kSrgbLinearSlope * x;
  const auto high = kSrgbScale * torch::pow(torch::clamp_min(x, kSrgbPowFloor), 1.0 / kSrgbGamma) - kSrgbOffset;
  return torch::where(x <= kSrgbLinearThreshold, low, high);
}

torch::Tensor srgb_to_linear(const torch::Tensor& s) {
  const auto low = s / kSrgbLinearSlope;
  const auto high = torch::pow(torch::clamp_min((s + kSrgbOffset) / kSrgbScale, kSrgbPowFloor), kSrgbGamma);
  return torch::where(s <= kSrgbLinearSlope * kSrgbLinearThreshold, low, high);
}

torch::Tensor tonemap(const torch::Tensor& ray_colour, const torch::Tensor& le_colour) {
  const auto linear = le_colour.defined() ? ray_colour + le_colour : ray_colour;
  return torch::clamp(linear_to_srgb(linear), 0.0, 1.0);
}

}  // namespace ablenerf
