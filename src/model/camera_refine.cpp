#include "model/camera_refine.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace ablenerf {

CameraRefineImpl::CameraRefineImpl(int64_t cameras, double lr_scale, bool centred, bool focal)
    : lr_scale_(lr_scale), centred_(centred) {
  if (cameras < 1) throw std::invalid_argument("CameraRefine: at least one camera");
  if (!(lr_scale > 0)) throw std::invalid_argument("CameraRefine: the learning-rate scale must be positive");
  param_ = register_parameter("correction", torch::zeros({cameras, 6}));
  if (focal) focal_ = register_parameter("focal", torch::zeros({1}));
}

void CameraRefineImpl::set_cameras(const torch::Tensor& c2w) {
  TORCH_CHECK(c2w.dim() == 3 && c2w.size(0) == cameras() && c2w.size(1) >= 3 && c2w.size(2) == 4,
              "CameraRefine::set_cameras: expected (", cameras(), ", 3, 4), got ", c2w.sizes());
  const auto pose = c2w.slice(1, 0, 3);
  set_centres(pose.select(2, 3));
  const auto axis = pose.select(2, 2).detach().to(param_.device(), param_.scalar_type());
  axes_ = (axis / axis.norm(2, 1, /*keepdim=*/true).clamp_min(1e-12)).clone();
}

torch::Tensor CameraRefineImpl::focal_scale() const {
  if (!focal_.defined()) return torch::ones({}, param_.options());
  return torch::exp(focal_.squeeze(0) * lr_scale_);
}

double CameraRefineImpl::focal_scale_value() const {
  return focal_.defined() ? std::exp(focal_.detach().cpu().to(torch::kDouble).item<double>() * lr_scale_) : 1.0;
}

Intrinsics CameraRefineImpl::refined(const Intrinsics& k) const {
  Intrinsics out = k;
  const double s = focal_scale_value();
  out.fx *= s, out.fy *= s;
  return out;
}

void CameraRefineImpl::set_centres(const torch::Tensor& centres) {
  TORCH_CHECK(centres.dim() == 2 && centres.size(0) == cameras() && centres.size(1) == 3,
              "CameraRefine::set_centres: expected (", cameras(), ", 3), got ", centres.sizes());
  centres_ = centres.detach().to(param_.device(), param_.scalar_type()).clone();
}

torch::Tensor CameraRefineImpl::correction() const {
  if (!centred_) return param_ * lr_scale_;
  const auto w = param_.slice(1, 0, 3), t = param_.slice(1, 3, 6);
  const auto wg = w.mean(0, /*keepdim=*/true);
  const auto c = centres_.defined() ? centres_.to(param_.device(), param_.scalar_type())
                                    : torch::zeros({cameras(), 3}, param_.options());
  const auto d = c - c.mean(0, /*keepdim=*/true);  // the centres about their mean
  // t_p - w_g x c_p, then its mean (the common shift) and its scaling about the mean out.
  const auto rest = t - torch::cross(wg.expand_as(c), c, 1);
  const auto shifted = rest - rest.mean(0, /*keepdim=*/true);
  const auto s = (shifted * d).sum() / (d * d).sum().clamp_min(1e-12);
  return torch::cat({w - wg, shifted - s * d}, 1) * lr_scale_;
}

torch::Tensor CameraRefineImpl::rotations() const {
  const auto w = correction().slice(1, 0, 3);
  const auto zero = torch::zeros_like(w.select(1, 0));
  const auto x = w.select(1, 0), y = w.select(1, 1), z = w.select(1, 2);
  // [w]x, the cross-product matrix: [w]x v = w x v.
  const auto k = torch::stack({zero, -z, y, z, zero, -x, -y, x, zero}, 1).view({-1, 3, 3});
  // Rodrigues' formula in closed form, exp([w]x) = I + a [w]x + b [w]x^2 with a = sin(q)/q and
  // b = (1 - cos q)/q^2 = sinc(q/2)^2 / 2 for the angle q = |w|, written without 1 - cos q (which
  // cancels in float32 at small angles). Not torch::matrix_exp: on CUDA it copies the matrices'
  // norms to the host to choose its degree, a synchronisation that a CUDA graph's capture refuses
  // (the first GPU run with camera refinement stopped there). At q^2 < 1e-4 (zero included, where
  // the closed form divides 0 by 0) the series to q^4, whose first dropped term is q^6/5040.
  const auto q2 = (w * w).sum(1).view({-1, 1, 1});
  const auto small = q2 < 1e-4;
  const auto q = torch::where(small, torch::ones_like(q2), q2).sqrt();
  const auto half = q * 0.5;
  const auto sinc_half = torch::sin(half) / half;
  const auto a = torch::where(small, 1 - q2 / 6 + q2 * q2 / 120, torch::sin(q) / q);
  const auto b = torch::where(small, 0.5 - q2 / 24 + q2 * q2 / 720, 0.5 * sinc_half * sinc_half);
  const auto eye = torch::eye(3, w.options()).expand_as(k);
  return eye + a * k + b * torch::matmul(k, k);
}

Rays CameraRefineImpl::forward(const Rays& rays, const torch::Tensor& photo) {
  const auto idx = photo.to(torch::kLong);
  const auto dtype = at::promote_types(rays.directions.scalar_type(), param_.scalar_type());
  const auto r = rotations().index_select(0, idx).to(dtype);                  // (B,3,3)
  const auto t = correction().slice(1, 3, 6).index_select(0, idx).to(dtype);  // (B,3)
  auto given = rays.directions.to(dtype);
  auto radii = rays.radii.to(dtype);
  if (focal_.defined()) {
    // The camera of focal length k f (see the header): across the axis / k, along it unchanged.
    TORCH_CHECK(axes_.defined(), "CameraRefine: focal refinement needs the cameras' axes (set_cameras)");
    const auto a = axes_.index_select(0, idx).to(dtype);
    const auto along = (given * a).sum(-1, /*keepdim=*/true) * a;
    const auto inv_k = 1.0 / focal_scale().to(dtype);
    given = along + (given - along) * inv_k;
    radii = radii * inv_k;
  }
  const auto d = torch::matmul(r, given.unsqueeze(-1)).squeeze(-1);
  return {rays.origins.to(dtype) + t, d, radii};
}

torch::Tensor CameraRefineImpl::corrected(const torch::Tensor& c2w) const {
  TORCH_CHECK(c2w.dim() == 3 && c2w.size(0) == cameras() && c2w.size(1) >= 3 && c2w.size(2) == 4,
              "CameraRefine::corrected: expected (", cameras(), ", 3, 4) camera-to-world matrices, got ", c2w.sizes());
  const auto pose = c2w.slice(1, 0, 3).to(param_.scalar_type());
  const auto rotation = torch::matmul(rotations(), pose.slice(2, 0, 3));
  const auto centre = pose.select(2, 3) + correction().slice(1, 3, 6);
  return torch::cat({rotation, centre.unsqueeze(-1)}, 2).to(c2w.scalar_type());
}

double coarse_to_fine_alpha(double fraction, double start, double end, int64_t degrees) {
  const double progress = end > start ? std::clamp((fraction - start) / (end - start), 0.0, 1.0) : 1.0;
  return 1.0 + static_cast<double>(degrees - 1) * progress;
}

torch::Tensor frequency_window_weights(double alpha, int64_t degrees) {
  std::vector<float> band(static_cast<size_t>(degrees));
  for (int64_t k = 0; k < degrees; ++k) {
    const double x = std::clamp(alpha - static_cast<double>(k), 0.0, 1.0);
    band[static_cast<size_t>(k)] = static_cast<float>(0.5 * (1.0 - std::cos(M_PI * x)));
  }
  const auto per_band = torch::tensor(band).repeat_interleave(3);  // three axes per band
  return torch::cat({per_band, per_band});                         // sines, then cosines
}

}  // namespace ablenerf
