#include "eval/camera_path.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <vector>

#include "data/capture.h"
#include "util/errors.h"
#include "util/json_file.h"

#include <nlohmann/json.hpp>

namespace ablenerf {
namespace {
// Below this norm a direction is treated as degenerate.
constexpr double kDegenerateNorm = 1e-9;
}  // namespace

PathKind parse_path_kind(const std::string& name, const std::string& source, const std::string& field) {
  if (name == "orbit") return PathKind::Orbit;
  if (name == "spiral") return PathKind::Spiral;
  throw InputError(source, field, "unknown camera path '" + name + "' (use orbit or spiral)");
}

CameraRig camera_rig(const torch::Tensor& c2w) {
  TORCH_CHECK(c2w.dim() == 3 && c2w.size(0) > 0 && c2w.size(1) >= 3 && c2w.size(2) == 4,
              "camera_rig: expected (N,3,4) poses, got ", c2w.sizes());
  const auto centres = c2w.slice(1, 0, 3).select(2, 3).to(torch::kDouble);  // (N,3)
  const auto dist = centres.norm(2, 1);
  // Elevation of each centre: asin(z / |c|); cameras at the origin carry no direction.
  const auto elev = torch::asin((centres.select(1, 2) / dist.clamp_min(kDegenerateNorm)).clamp(-1.0, 1.0));
  CameraRig rig;
  rig.distance = dist.mean().item<double>();
  rig.elevation = elev.mean().item<double>();
  rig.elevation_min = elev.min().item<double>();
  rig.elevation_max = elev.max().item<double>();
  // Azimuths in increasing order; the largest gap between neighbours (wrapping round) decides
  // whether the cameras went all the way round.
  const auto az = torch::atan2(centres.select(1, 1), centres.select(1, 0));
  std::vector<double> a(static_cast<size_t>(az.size(0)));
  for (size_t i = 0; i < a.size(); ++i) a[i] = az[static_cast<int64_t>(i)].item<double>();
  std::sort(a.begin(), a.end());
  double gap = a.front() + 2 * M_PI - a.back();  // from the last back round to the first
  double start = a.front();
  for (size_t i = 1; i < a.size(); ++i)
    if (a[i] - a[i - 1] > gap) gap = a[i] - a[i - 1], start = a[i];
  if (gap > kOpenArcGapRad) {
    rig.azimuth_start = start;
    rig.azimuth_span = 2 * M_PI - gap;
  }
  return rig;
}

torch::Tensor look_at(const torch::Tensor& eye, const torch::Tensor& target, const torch::Tensor& up) {
  const auto e = eye.to(torch::kDouble), t = target.to(torch::kDouble), u = up.to(torch::kDouble);
  // The camera looks along -z, so its z axis points from the target back to the eye.
  auto z = e - t;
  const double zn = z.norm().item<double>();
  if (zn < kDegenerateNorm) throw std::invalid_argument("look_at: eye equals target");
  z = z / zn;
  auto x = torch::linalg_cross(u, z);
  const double xn = x.norm().item<double>();
  if (xn < kDegenerateNorm) throw std::invalid_argument("look_at: view direction parallel to up");
  x = x / xn;
  const auto y = torch::linalg_cross(z, x);                // unit: z and x are orthonormal
  return torch::stack({x, y, z, e}, 1).to(torch::kFloat);  // columns: right, up, back, centre
}

torch::Tensor camera_path(PathKind kind, int frames, const CameraRig& rig) {
  if (frames < 1) throw std::invalid_argument("camera_path: frames must be >= 1");
  const auto origin = torch::zeros({3}, torch::kDouble);
  const auto up = torch::tensor({0.0, 0.0, 1.0}, torch::kDouble);
  std::vector<torch::Tensor> poses;
  poses.reserve(static_cast<size_t>(frames));
  const double amplitude =
      std::clamp(std::min({kSpiralAmplitudeRad, rig.elevation_max - rig.elevation, rig.elevation - rig.elevation_min}),
                 0.0, kSpiralAmplitudeRad);
  for (int k = 0; k < frames; ++k) {
    const double phase = 2.0 * M_PI * k / frames;
    const double azimuth =
        rig.full_circle() ? phase : rig.azimuth_start + rig.azimuth_span * 0.5 * (1 - std::cos(phase));
    double elev = rig.elevation;
    if (kind == PathKind::Spiral) elev += amplitude * std::sin(kSpiralCycles * phase);
    elev = std::clamp(elev, -kMaxElevationRad, kMaxElevationRad);
    const double r = rig.distance;
    const auto eye = torch::tensor(
        {r * std::cos(elev) * std::cos(azimuth), r * std::cos(elev) * std::sin(azimuth), r * std::sin(elev)},
        torch::kDouble);
    poses.push_back(look_at(eye, origin, up));
  }
  return torch::stack(poses);
}

torch::Tensor forward_facing_path(PathKind kind, int frames, const torch::Tensor& c2w) {
  if (frames < 1) throw std::invalid_argument("forward_facing_path: frames must be >= 1");
  TORCH_CHECK(c2w.dim() == 3 && c2w.size(0) > 0 && c2w.size(2) == 4, "forward_facing_path: expected (N,3,4) poses");
  const auto centres = c2w.slice(1, 0, 3).select(2, 3).to(torch::kDouble);
  const double rx = std::max(centres.select(1, 0).abs().max().item<double>(), kDegenerateNorm);
  const double ry = std::max(centres.select(1, 1).abs().max().item<double>(), kDegenerateNorm);
  const double z0 = centres.select(1, 2).mean().item<double>();
  const auto target = torch::tensor({0.0, 0.0, -kForwardFocusDepth}, torch::kDouble);
  const auto up = torch::tensor({0.0, 1.0, 0.0}, torch::kDouble);
  std::vector<torch::Tensor> poses;
  for (int k = 0; k < frames; ++k) {
    const double phase = 2.0 * M_PI * k / frames;
    const double dz = kind == PathKind::Spiral ? 0.5 * std::min(rx, ry) * std::sin(kSpiralCycles * phase) : 0.0;
    const auto eye = torch::tensor({rx * std::cos(phase), ry * std::sin(phase), z0 + dz}, torch::kDouble);
    poses.push_back(look_at(eye, target, up));
  }
  return torch::stack(poses);
}

bool is_path_file(const std::string& name) { return name.size() > 5 && name.compare(name.size() - 5, 5, ".json") == 0; }

torch::Tensor read_path_file(const std::string& path) {
  const nlohmann::json j = read_json_file(path);
  if (!j.is_object() || j.value("ablenerf_path", 0) != 1)
    throw InputError(path, "ablenerf_path", "not a camera path recorded by `ablenerf view` (version 1)");
  if (j.value("coordinates", std::string()) != "scene")
    throw InputError(path, "coordinates", "must be \"scene\" (the run's scene frame)");
  if (!j.contains("poses") || !j.at("poses").is_array() || j.at("poses").empty())
    throw InputError(path, "poses", "expected a non-empty array");
  const auto& list = j.at("poses");
  auto out = torch::empty({static_cast<int64_t>(list.size()), 3, 4}, torch::kFloat);
  for (size_t i = 0; i < list.size(); ++i) {
    const std::string field = "poses[" + std::to_string(i) + "]";
    const auto& p = list[i];
    if (!p.is_array() || p.size() != 12) throw InputError(path, field, "expected 12 numbers");
    double m[3][4];
    for (size_t k = 0; k < 12; ++k) {
      if (!p[k].is_number()) throw InputError(path, field, "expected 12 numbers");
      m[k / 4][k % 4] = p[k].get<double>();
    }
    // Finite and rigid, as every dataset pose (the page writes 6 decimals, well inside the tolerance).
    const Pose34 pose = checked_pose(m, path, field);
    std::memcpy(out[static_cast<int64_t>(i)].data_ptr<float>(), pose.data(), sizeof(float) * pose.size());
  }
  return out;
}

}  // namespace ablenerf
