#include "data/rays.h"

#include <algorithm>
#include <cmath>

#include "data/lens.h"

namespace ablenerf {

namespace {
const double kRadiusScale = 2.0 / std::sqrt(12.0);
}  // namespace

CameraTable CameraTable::of(const std::vector<Intrinsics>& cams, const torch::Device& device) {
  const auto n = static_cast<int64_t>(cams.size());
  auto params = torch::empty({n, 4 + kLensCoeffs}, torch::kDouble);
  auto model = torch::empty({n}, torch::kLong);
  auto p = params.accessor<double, 2>();
  auto m = model.accessor<int64_t, 1>();
  for (int64_t i = 0; i < n; ++i) {
    const Intrinsics& k = cams[static_cast<size_t>(i)];
    p[i][0] = k.fx;
    p[i][1] = k.fy;
    p[i][2] = k.cx;
    p[i][3] = k.cy;
    for (int c = 0; c < kLensCoeffs; ++c) p[i][4 + c] = k.dist[static_cast<size_t>(c)];
    m[i] = static_cast<int64_t>(k.model);
  }
  std::vector<LensModel> models;
  for (const Intrinsics& k : cams)
    if (std::find(models.begin(), models.end(), k.model) == models.end()) models.push_back(k.model);
  return CameraTable{params, model, models}.to(device);
}

CameraTable CameraTable::index(const torch::Tensor& rows) const {
  const auto r = rows.to(params.device());
  return {params.index_select(0, r), model.index_select(0, r), models};
}

CameraTable CameraTable::repeat_first(int64_t n) const {
  return {params.slice(0, 0, 1).expand({n, params.size(1)}), model.slice(0, 0, 1).expand({n}), models};
}

CameraTable CameraTable::to(const torch::Device& device) const { return {params.to(device), model.to(device), models}; }

double pixel_radius(const Intrinsics& k) { return (1.0 / k.fy) * kRadiusScale; }

LensCoordinates lens_coordinates(const torch::Tensor& col, const torch::Tensor& row, const CameraTable& cams) {
  const auto f64 = col.options().dtype(torch::kDouble);
  const auto f32 = col.options().dtype(torch::kFloat);
  const auto p = cams.params.to(f64);
  const auto fx = p.select(1, 0), fy = p.select(1, 1), cx = p.select(1, 2), cy = p.select(1, 3);
  // Normalised coordinates in OpenCV axes (y down), in float64 for the lens inverse.
  const auto xd = (col.to(f64) + 0.5 - cx) / fx;
  const auto yd = (row.to(f64) + 0.5 - cy) / fy;
  if (cams.all_pinhole()) return {xd.to(f32), yd.to(f32), (kRadiusScale / fy).unsqueeze(1).to(f32)};
  const CameraTable lens{p, cams.model.to(col.device()), cams.models};
  const auto xy = undistort_points(lens, torch::stack({xd, yd}, 1));
  // One pixel down in the image is 1/fy in distorted coordinates.
  const auto radii = (undistorted_step_y(lens, xy).norm(2, 1) * (kRadiusScale / fy)).unsqueeze(1).to(f32);
  return {xy.select(1, 0).to(f32), xy.select(1, 1).to(f32), radii};
}

Rays rays_from_lens_coordinates(const torch::Tensor& c2w, const LensCoordinates& lens) {
  const auto opts = c2w.options().dtype(torch::kFloat);
  // OpenGL camera axes: y up, looking down -z.
  auto dirs_cam = torch::stack({lens.x, -lens.y, -torch::ones_like(lens.x)}, -1).to(opts);  // (B,3)
  auto rot = c2w.slice(1, 0, 3).slice(2, 0, 3).to(torch::kFloat);                           // (B,3,3)
  auto dirs = torch::bmm(rot, dirs_cam.unsqueeze(-1)).squeeze(-1);
  auto origins = c2w.slice(1, 0, 3).select(2, 3).to(torch::kFloat).contiguous();
  return {origins, dirs.contiguous(), lens.radii.to(opts).contiguous()};
}

Rays rays_for_pixels(const torch::Tensor& c2w, const torch::Tensor& col, const torch::Tensor& row,
                     const CameraTable& cams) {
  return rays_from_lens_coordinates(c2w, lens_coordinates(col.to(c2w.device()), row.to(c2w.device()), cams));
}

Rays rays_for_pixels(const torch::Tensor& c2w, const torch::Tensor& col, const torch::Tensor& row,
                     const Intrinsics& k) {
  return rays_for_pixels(c2w, col, row, CameraTable::of({k}, c2w.device()).repeat_first(col.size(0)));
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
