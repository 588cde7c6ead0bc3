#include "geometry/depth_points.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "data/rays.h"
#include "util/errors.h"

namespace ablenerf {

bool CropBox::contains(const std::array<double, 3>& p) const {
  for (int i = 0; i < 3; ++i)
    if (p[static_cast<size_t>(i)] < lo[static_cast<size_t>(i)] ||
        p[static_cast<size_t>(i)] > hi[static_cast<size_t>(i)])
      return false;
  return true;
}

torch::Tensor CropBox::inside(const torch::Tensor& xyz) const {
  const auto l = torch::tensor({lo[0], lo[1], lo[2]}, xyz.options());
  const auto h = torch::tensor({hi[0], hi[1], hi[2]}, xyz.options());
  return (xyz >= l).all(-1) & (xyz <= h).all(-1);
}

double CropBox::diagonal() const {
  double s = 0;
  for (size_t i = 0; i < 3; ++i) s += (hi[i] - lo[i]) * (hi[i] - lo[i]);
  return std::sqrt(s);
}

CropBox CropBox::around(const torch::Tensor& xyz, double share, double margin) {
  TORCH_CHECK(xyz.dim() == 2 && xyz.size(1) == 3 && xyz.size(0) > 0, "CropBox::around: expected (N>0,3) points");
  // Quantiles of an even subset of at most 2^20 rows (torch::quantile sorts its whole input).
  const int64_t stride = std::max<int64_t>(1, (xyz.size(0) + (int64_t{1} << 20) - 1) >> 20);
  const auto p = xyz.slice(0, 0, xyz.size(0), stride).to(torch::kDouble);
  const auto q = torch::tensor({(1 - share) / 2, (1 + share) / 2}, torch::kDouble);
  const auto bounds = torch::quantile(p, q, 0);  // (2,3)
  CropBox b;
  for (size_t i = 0; i < 3; ++i) {
    const double lo = bounds[0][static_cast<int64_t>(i)].item<double>();
    const double hi = bounds[1][static_cast<int64_t>(i)].item<double>();
    const double pad = std::max(margin * (hi - lo), 1e-9);
    b.lo[i] = lo - pad;
    b.hi[i] = hi + pad;
  }
  return b;
}

CropBox CropBox::parse(const std::string& text, const std::string& option) {
  std::vector<double> v;
  std::stringstream in(text);
  std::string item;
  while (std::getline(in, item, ',')) {
    try {
      size_t used = 0;
      v.push_back(std::stod(item, &used));
      if (used != item.size() || !std::isfinite(v.back())) throw std::invalid_argument(item);
    } catch (const std::exception&) {
      throw InputError(option, "'" + item + "'", "expected a number (xmin,ymin,zmin,xmax,ymax,zmax)");
    }
  }
  if (v.size() != 6) throw InputError(option, text, "expected six numbers: xmin,ymin,zmin,xmax,ymax,zmax");
  CropBox b;
  for (size_t i = 0; i < 3; ++i) {
    b.lo[i] = v[i];
    b.hi[i] = v[i + 3];
    if (!(b.hi[i] > b.lo[i])) throw InputError(option, text, "empty box: every max must exceed its min");
  }
  return b;
}

PointSet points_from_depth(const torch::Tensor& c2w, const Intrinsics& k, const torch::Tensor& depth,
                           const torch::Tensor& rgb, double near, double far, const CropBox& crop,
                           const torch::Tensor& keep) {
  TORCH_CHECK(depth.dim() == 2 && depth.size(0) == k.height && depth.size(1) == k.width,
              "points_from_depth: depth must be (H,W) of the camera");
  const Rays rays = rays_for_image(c2w.to(torch::kFloat), k);
  const auto d = depth.reshape({-1}).to(torch::kFloat);
  auto ok = (d > near) & (d < far) & torch::isfinite(d);
  if (keep.defined()) ok = ok & keep.reshape({-1});
  const auto xyz = rays.origins + rays.directions * d.unsqueeze(-1);
  ok = ok & crop.inside(xyz);
  const auto idx = ok.nonzero().squeeze(-1);
  PointSet out;
  out.xyz = xyz.index_select(0, idx).contiguous();
  out.rgb = rgb.reshape({-1, 3}).to(torch::kFloat).index_select(0, idx).contiguous();
  return out;
}

namespace {
// The scene frame's rotation R (row-major) as a (3,3) float64 tensor.
torch::Tensor rotation_of(const SceneFrame& scene) {
  return torch::tensor(std::vector<double>(scene.rotation.begin(), scene.rotation.end()), torch::kDouble)
      .reshape({3, 3});
}
}  // namespace

torch::Tensor points_to_capture(const torch::Tensor& xyz, const SceneFrame& scene) {
  // point_to_scene: p_s = scale * R (p - centre), so p = R^T p_s / scale + centre.
  const auto c = torch::tensor(std::vector<double>(scene.centre.begin(), scene.centre.end()), torch::kDouble);
  return (torch::matmul(xyz.to(torch::kDouble), rotation_of(scene)) / scene.scale + c).to(xyz.scalar_type());
}

torch::Tensor normals_to_capture(const torch::Tensor& normals, const SceneFrame& scene) {
  return torch::matmul(normals.to(torch::kDouble), rotation_of(scene)).to(normals.scalar_type());
}

PointSet concat_points(const std::vector<PointSet>& sets) {
  std::vector<torch::Tensor> xyz, rgb, normals;
  bool all_normals = true;
  for (const auto& s : sets) {
    if (s.size() == 0) continue;
    xyz.push_back(s.xyz);
    rgb.push_back(s.rgb);
    all_normals = all_normals && s.normals.defined();
    if (s.normals.defined()) normals.push_back(s.normals);
  }
  PointSet out;
  if (xyz.empty()) {
    out.xyz = torch::zeros({0, 3});
    out.rgb = torch::zeros({0, 3});
    return out;
  }
  out.xyz = torch::cat(xyz);
  out.rgb = torch::cat(rgb);
  if (all_normals) out.normals = torch::cat(normals);
  return out;
}

}  // namespace ablenerf
