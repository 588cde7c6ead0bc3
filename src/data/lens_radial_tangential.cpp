// OpenCV's radial-tangential lens (camera.h, LensModel::RadialTangential). The inverse is Newton's
// method on the 2x2 system distort(x, y) = (xd, yd) started at the distorted point, as COLMAP and
// nerfstudio do; 20 fixed iterations reach float64 round-off for the coefficients real lenses have
// (tests/data/lens_test.cpp checks distort(undistort(p)) == p to 1e-9 over whole images).
#include "data/lens.h"

namespace ablenerf {

namespace {
constexpr double kRtMinDeterminant = 1e-12;

struct Coeffs {
  torch::Tensor k1, k2, k3, p1, p2;
  explicit Coeffs(const torch::Tensor& c)
      : k1(c.select(1, kK1)), k2(c.select(1, kK2)), k3(c.select(1, kK3)), p1(c.select(1, kP1)), p2(c.select(1, kP2)) {}
};
}  // namespace

torch::Tensor radial_tangential_distort(const torch::Tensor& xy, const torch::Tensor& coeffs) {
  const Coeffs c(coeffs);
  const auto x = xy.select(1, 0), y = xy.select(1, 1);
  const auto r2 = x * x + y * y;
  const auto radial = 1 + r2 * (c.k1 + r2 * (c.k2 + r2 * c.k3));
  const auto xd = x * radial + 2 * c.p1 * x * y + c.p2 * (r2 + 2 * x * x);
  const auto yd = y * radial + c.p1 * (r2 + 2 * y * y) + 2 * c.p2 * x * y;
  return torch::stack({xd, yd}, 1);
}

torch::Tensor radial_tangential_undistort(const torch::Tensor& xy_distorted, const torch::Tensor& coeffs) {
  const Coeffs c(coeffs);
  const auto xd = xy_distorted.select(1, 0), yd = xy_distorted.select(1, 1);
  auto x = xd.clone(), y = yd.clone();
  for (int it = 0; it < kLensNewtonIterations; ++it) {
    const auto r2 = x * x + y * y;
    const auto radial = 1 + r2 * (c.k1 + r2 * (c.k2 + r2 * c.k3));
    // d radial / d(r^2); d(r^2)/dx = 2x.
    const auto dradial = c.k1 + r2 * (2 * c.k2 + 3 * c.k3 * r2);
    const auto fx = x * radial + 2 * c.p1 * x * y + c.p2 * (r2 + 2 * x * x) - xd;
    const auto fy = y * radial + c.p1 * (r2 + 2 * y * y) + 2 * c.p2 * x * y - yd;
    const auto j11 = radial + 2 * x * x * dradial + 2 * c.p1 * y + 6 * c.p2 * x;
    const auto j12 = 2 * x * y * dradial + 2 * c.p1 * x + 2 * c.p2 * y;
    const auto j21 = j12;  // the Jacobian is symmetric: d fy/dx = 2xy dradial + 2 p1 x + 2 p2 y
    const auto j22 = radial + 2 * y * y * dradial + 6 * c.p1 * y + 2 * c.p2 * x;
    auto det = j11 * j22 - j12 * j21;
    // A singular Jacobian (far outside a lens's valid field) leaves the point where it is.
    const auto ok = det.abs() > kRtMinDeterminant;
    det = torch::where(ok, det, torch::ones_like(det));
    const auto step_x = torch::where(ok, (fx * j22 - fy * j12) / det, torch::zeros_like(det));
    const auto step_y = torch::where(ok, (fy * j11 - fx * j21) / det, torch::zeros_like(det));
    x = x - step_x;
    y = y - step_y;
  }
  return torch::stack({x, y}, 1);
}

}  // namespace ablenerf
