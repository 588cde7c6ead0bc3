#include "data/lens.h"

namespace ablenerf {

namespace {

using LensFn = torch::Tensor (*)(const torch::Tensor&, const torch::Tensor&);

torch::Tensor identity(const torch::Tensor& xy, const torch::Tensor&) { return xy; }

LensFn forward_of(LensModel m) {
  switch (m) {
    case LensModel::RadialTangential: return radial_tangential_distort;
    case LensModel::Fisheye: return fisheye_distort;
    case LensModel::Pinhole: break;
  }
  return identity;
}

LensFn inverse_of(LensModel m) {
  switch (m) {
    case LensModel::RadialTangential: return radial_tangential_undistort;
    case LensModel::Fisheye: return fisheye_undistort;
    case LensModel::Pinhole: break;
  }
  return identity;
}

// Every model the table holds, applied to every row, each row keeping its own model's result
// (torch::where: no host read-back). One model: applied directly.
torch::Tensor apply(const CameraTable& cams, const torch::Tensor& xy, LensFn (*pick)(LensModel)) {
  const auto coeffs = cams.params.slice(1, 4, 4 + kLensCoeffs);
  if (cams.models.size() == 1) return pick(cams.models[0])(xy, coeffs);
  torch::Tensor out = xy;
  for (LensModel m : cams.models) {
    const auto rows = (cams.model == static_cast<int64_t>(m)).unsqueeze(1);
    out = torch::where(rows, pick(m)(xy, coeffs), out);
  }
  return out;
}

constexpr double kLensStep = 1e-6;

}  // namespace

torch::Tensor distort_points(const CameraTable& cams, const torch::Tensor& xy) { return apply(cams, xy, forward_of); }

torch::Tensor undistort_points(const CameraTable& cams, const torch::Tensor& xy) { return apply(cams, xy, inverse_of); }

torch::Tensor undistorted_step_y(const CameraTable& cams, const torch::Tensor& xy) {
  if (cams.all_pinhole())
    return torch::stack({torch::zeros_like(xy.select(1, 0)), torch::ones_like(xy.select(1, 0))}, 1);
  // The two offsets made on xy's device (torch::tensor would copy from the host, a synchronising
  // copy that a CUDA graph capturing the training step refuses).
  const auto steps = torch::eye(2, xy.options()) * kLensStep;
  const auto ex = steps[0], ey = steps[1];
  const auto dx = (distort_points(cams, xy + ex) - distort_points(cams, xy - ex)) / (2 * kLensStep);  // column d/dx
  const auto dy = (distort_points(cams, xy + ey) - distort_points(cams, xy - ey)) / (2 * kLensStep);  // column d/dy
  const auto a = dx.select(1, 0), b = dy.select(1, 0), c = dx.select(1, 1), d = dy.select(1, 1);
  // J = [[a, b], [c, d]]; the second column of J^-1 is (-b, a) / det.
  const auto det = a * d - b * c;
  return torch::stack({-b / det, a / det}, 1);
}

}  // namespace ablenerf
