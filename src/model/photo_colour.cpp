#include "model/photo_colour.h"

#include <stdexcept>

#include "model/tonemap.h"

namespace ablenerf {

// The parameters' names under the module ("photo_colour." + these in a weights file).
const char* const kPhotoColourAffineWeight = "photo_colour.delta";
const char* const kPhotoColourGainWeight = "photo_colour.log_gain";

PhotoColourImpl::PhotoColourImpl(int64_t photos, PhotoColourMap map) : map_(map) {
  if (photos < 1) throw std::invalid_argument("PhotoColour: at least one photo");
  if (map_ == PhotoColourMap::Affine)
    param_ = register_parameter("delta", torch::zeros({photos, 3, 4}));
  else
    param_ = register_parameter("log_gain", torch::zeros({photos, 3}));
}

torch::Tensor PhotoColourImpl::forward(const torch::Tensor& rgb, const torch::Tensor& photo) {
  // In the wider of the two dtypes (the model's colours are float32; a float64 model's maps stay float64).
  const auto dtype = at::promote_types(rgb.scalar_type(), param_.scalar_type());
  const auto c = rgb.to(dtype);
  // Each map minus the maps' mean: the average photo's map is exactly the identity, so the scene keeps
  // the photos' common look (a common change of every map would otherwise darken or tint the scene).
  const auto centred = (param_ - param_.mean(0, /*keepdim=*/true)) * lr_scale();
  const auto d = centred.index_select(0, photo.to(torch::kLong)).to(dtype);
  if (map_ == PhotoColourMap::Gain) {
    // The rendered colour is clamp(srgb(x), 0, 1) of the linear light x (model/tonemap.h): back to x
    // (exact below saturation), times the photo's gains, through the curve, saturating at 1.
    const auto light = srgb_to_linear(c.clamp(0.0, 1.0));
    return torch::clamp(linear_to_srgb(light * torch::exp(d)), 0.0, 1.0);
  }
  const auto linear = torch::matmul(d.slice(2, 0, 3), c.unsqueeze(-1)).squeeze(-1);  // (B,3,4) maps
  return c + linear + d.select(2, 3);
}

torch::Tensor PhotoColourImpl::look(const torch::Tensor& image, int64_t photo) {
  TORCH_CHECK(photo >= 0 && photo < photos(), "PhotoColour::look: photo ", photo, " of ", photos());
  const auto flat = image.reshape({-1, 3});
  const auto which =
      torch::full({flat.size(0)}, photo, torch::TensorOptions().dtype(torch::kLong).device(flat.device()));
  return forward(flat, which).to(torch::kFloat).clamp(0.0, 1.0).reshape(image.sizes());
}

}  // namespace ablenerf
