#pragma once
// Stage 7 (docs/MODEL.md, section 7): the two branch colours are summed in linear space, mapped through the sRGB
// transfer curve and hard-clipped to [0,1] (zero gradient where saturated, like the release).
#include <torch/torch.h>

namespace ablenerf {

constexpr double kSrgbLinearThreshold = 0.0031308;
constexpr double kSrgbLinearSlope = 12.92;
constexpr double kSrgbScale = 1.055;
constexpr double kSrgbOffset = 0.055;
constexpr double kSrgbGamma = 2.4;
constexpr double kSrgbPowFloor = 1e-7;  // keeps pow's gradient finite in the unused branch

// Linear -> sRGB (no clipping).
torch::Tensor linear_to_srgb(const torch::Tensor& x);
// sRGB -> linear, the inverse of linear_to_srgb on [0, 1] (IEC 61966-2-1's decoding: the linear
// segment up to 12.92 x the threshold, then the power curve).
torch::Tensor srgb_to_linear(const torch::Tensor& s);

// clamp(sRGB(ray_colour + le_colour), 0, 1). le_colour may be undefined (no-LE ablation).
torch::Tensor tonemap(const torch::Tensor& ray_colour, const torch::Tensor& le_colour);

}  // namespace ablenerf
