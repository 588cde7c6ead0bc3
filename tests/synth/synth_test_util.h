#pragma once
// Independent references for the synth tests: the closed-form ray-sphere intersection (full
// quadratic, written separately from the tracer's half-b form) and Blender-json camera rays.
#include <array>
#include <cmath>
#include <nlohmann/json.hpp>
#include <string>

namespace ablenerf::synth_test {

using V3 = std::array<double, 3>;

inline V3 sub(const V3& a, const V3& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
inline double dot3(const V3& a, const V3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

// Smallest positive root of |o + t d - c|^2 = r^2 via t = (-b - sqrt(b^2 - 4ac)) / 2a, or -1.
inline double ray_sphere(const V3& o, const V3& d, const V3& c, double r) {
  const V3 oc = sub(o, c);
  const double a = dot3(d, d), b = 2.0 * dot3(d, oc), cc = dot3(oc, oc) - r * r;
  const double disc = b * b - 4.0 * a * cc;
  if (disc < 0) return -1.0;
  const double t0 = (-b - std::sqrt(disc)) / (2.0 * a), t1 = (-b + std::sqrt(disc)) / (2.0 * a);
  if (t0 > 0) return t0;
  return t1 > 0 ? t1 : -1.0;
}

// A camera read from a transforms json frame: pose rows and focal length for a W-pixel image.
struct JsonCamera {
  double m[3][4];
  double focal;
  int width, height;
  V3 origin() const { return {m[0][3], m[1][3], m[2][3]}; }
  // Unnormalised direction through pixel coordinates (px, py), the loader's convention.
  V3 dir(double px, double py) const {
    const double x = (px - 0.5 * width) / focal, y = -(py - 0.5 * height) / focal, z = -1.0;
    return {m[0][0] * x + m[0][1] * y + m[0][2] * z, m[1][0] * x + m[1][1] * y + m[1][2] * z,
            m[2][0] * x + m[2][1] * y + m[2][2] * z};
  }
  // World point -> continuous pixel coordinates; returns false behind the camera.
  bool project(const V3& p, double& px, double& py) const {
    const V3 q = sub(p, origin());
    double cam[3];
    for (int c = 0; c < 3; ++c) cam[c] = m[0][c] * q[0] + m[1][c] * q[1] + m[2][c] * q[2];  // R^T q
    if (cam[2] >= 0) return false;
    px = focal * cam[0] / -cam[2] + 0.5 * width;
    py = -focal * cam[1] / -cam[2] + 0.5 * height;
    return true;
  }
};

inline JsonCamera camera_from_json(const nlohmann::json& transforms, size_t frame, int width, int height) {
  JsonCamera cam{};
  const auto& tm = transforms.at("frames").at(frame).at("transform_matrix");
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) cam.m[r][c] = tm.at(r).at(c).get<double>();
  cam.width = width;
  cam.height = height;
  cam.focal = 0.5 * width / std::tan(0.5 * transforms.at("camera_angle_x").get<double>());
  return cam;
}

}  // namespace ablenerf::synth_test
