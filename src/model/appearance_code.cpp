#include "model/appearance_code.h"

#include <stdexcept>

namespace ablenerf {

const char* const kAppearanceCodeWeight = "appearance_code.codes";

AppearanceCodeImpl::AppearanceCodeImpl(int64_t photos, int64_t width) {
  if (photos < 1 || width < 1) throw std::invalid_argument("AppearanceCode: at least one photo and one number");
  codes_ = register_parameter("codes", torch::zeros({photos, width}));
}

torch::Tensor AppearanceCodeImpl::forward(const torch::Tensor& photo) {
  // Minus the codes' mean: the average photo's code is exactly zero, so the scene rendered without a
  // code keeps the photos' common look (as the colour maps are centred, model/photo_colour.h).
  const auto centred = codes_ - codes_.mean(0, /*keepdim=*/true);
  return centred.index_select(0, photo.to(torch::kLong).to(codes_.device()));
}

torch::Tensor AppearanceCodeImpl::look(int64_t photo) {
  TORCH_CHECK(photo >= 0 && photo < photos(), "AppearanceCode::look: photo ", photo, " of ", photos());
  const torch::NoGradGuard no_grad;
  return forward(torch::full({1}, photo, torch::TensorOptions().dtype(torch::kLong)));
}

}  // namespace ablenerf
