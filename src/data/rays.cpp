#include "data/rays.h"

#include <cmath>

namespace ablenerf {

double pixel_radius(const Intrinsics& k) { return (1.0 / k.fy) * 2.0 / std::sqrt(12.0); }

Rays rays_for_pixels(const torch::Tensor& c2w, const torch::Tensor& col, const torch::Tensor& row,
                     const Intrinsics& k) {
  const auto opts = c2w.options().dtype(torch::kFloat);
  auto x = (col.to(torch::kFloat) + 0.5f - static_cast<float>(k.cx)) / static_cast<float>(k.fx);
  auto y = -(row.to(torch::kFloat) + 0.5f - static_cast<float>(k.cy)) / static_cast<float>(k.fy);
  auto dirs_cam = torch::stack({x, y, -torch::ones_like(x)}, -1);  // (B,3)
  auto rot = c2w.slice(1, 0, 3).slice(2, 0, 3).to(torch::kFloat);  // (B,3,3)
  auto dirs = torch::bmm(rot, dirs_cam.unsqueeze(-1)).squeeze(-1);
  auto origins = c2w.slice(1, 0, 3).select(2, 3).to(torch::kFloat).contiguous();
  auto radii = torch::full({x.size(0), 1}, pixel_radius(k), opts);
  return {origins, dirs.contiguous(), radii};
}

Rays rays_for_image(const torch::Tensor& c2w, const Intrinsics& k) {
  const auto dev = c2w.device();
  auto rows = torch::arange(k.height, torch::TensorOptions().dtype(torch::kLong).device(dev));
  auto cols = torch::arange(k.width, torch::TensorOptions().dtype(torch::kLong).device(dev));
  auto grid = torch::meshgrid({rows, cols}, "ij");
  auto r = grid[0].reshape({-1}), c = grid[1].reshape({-1});
  auto pose = c2w.unsqueeze(0).expand({r.size(0), c2w.size(0), c2w.size(1)});
  return rays_for_pixels(pose, c, r, k);
}

}  // namespace ablenerf
