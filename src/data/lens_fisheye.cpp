// OpenCV's fisheye lens (camera.h, LensModel::Fisheye; COLMAP's OPENCV_FISHEYE). The inverse solves
// the 1-D polynomial theta (1 + k1 theta^2 + ... + k4 theta^8) = theta_d by Newton's method from
// theta = theta_d, then scales the point by tan(theta) / theta_d. Angles are kept below
// kFisheyeMaxTheta: the ray generator's directions lie on the plane z = -1.
#include <cmath>

#include "data/lens.h"

namespace ablenerf {

namespace {
constexpr double kFeTiny = 1e-12;

torch::Tensor poly(const torch::Tensor& t2, const torch::Tensor& c) {
  return 1 + t2 * (c.select(1, kK1) + t2 * (c.select(1, kK2) + t2 * (c.select(1, kK3) + t2 * c.select(1, kK4))));
}
}  // namespace

torch::Tensor fisheye_distort(const torch::Tensor& xy, const torch::Tensor& coeffs) {
  const auto r = xy.norm(2, 1);
  const auto theta = torch::atan(r);
  const auto theta_d = theta * poly(theta * theta, coeffs);
  // theta_d / r -> 1 as r -> 0.
  const auto scale = torch::where(r > kFeTiny, theta_d / r.clamp_min(kFeTiny), torch::ones_like(r));
  return xy * scale.unsqueeze(1);
}

torch::Tensor fisheye_undistort(const torch::Tensor& xy_distorted, const torch::Tensor& coeffs) {
  const auto theta_d = xy_distorted.norm(2, 1);
  auto theta = theta_d.clone();
  const auto k1 = coeffs.select(1, kK1), k2 = coeffs.select(1, kK2), k3 = coeffs.select(1, kK3),
             k4 = coeffs.select(1, kK4);
  for (int it = 0; it < kLensNewtonIterations; ++it) {
    const auto t2 = theta * theta;
    const auto f = theta * poly(t2, coeffs) - theta_d;
    // d/dtheta of theta + k1 theta^3 + k2 theta^5 + k3 theta^7 + k4 theta^9.
    const auto df = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)));
    const auto ok = df.abs() > kFeTiny;
    theta = theta - torch::where(ok, f / torch::where(ok, df, torch::ones_like(df)), torch::zeros_like(f));
    theta = theta.clamp(0.0, kFisheyeMaxTheta);
  }
  const auto scale =
      torch::where(theta_d > kFeTiny, torch::tan(theta) / theta_d.clamp_min(kFeTiny), torch::ones_like(theta));
  return xy_distorted * scale.unsqueeze(1);
}

}  // namespace ablenerf
