#include "eval/pose_error.h"

#include <cmath>

namespace ablenerf {

namespace {

torch::Tensor rotations(const torch::Tensor& c2w) { return c2w.to(torch::kDouble).slice(1, 0, 3).slice(2, 0, 3); }
torch::Tensor centres(const torch::Tensor& c2w) { return c2w.to(torch::kDouble).slice(1, 0, 3).select(2, 3); }

// Angles in degrees from cosines, clamped to [-1, 1] against rounding.
torch::Tensor degrees_of(const torch::Tensor& cosine) { return cosine.clamp(-1.0, 1.0).acos() * (180.0 / M_PI); }

}  // namespace

PoseErrors pose_errors(const torch::Tensor& est, const torch::Tensor& truth, const torch::Tensor& points) {
  TORCH_CHECK(est.dim() == 3 && est.size(1) >= 3 && est.size(2) == 4 && truth.sizes() == est.sizes() && est.size(0) > 0,
              "pose_errors: est and truth must be the same (N,3,4) or (N,4,4), N > 0");
  TORCH_CHECK(points.dim() == 2 && points.size(1) == 3 && points.size(0) > 0, "pose_errors: points must be (P,3)");
  const auto ra = rotations(est), rb = rotations(truth), ca = centres(est), cb = centres(truth);
  PoseErrors out;
  // trace(R_a^T R_b) = 1 + 2 cos(angle).
  const auto trace = (ra * rb).sum({1, 2});
  out.rotation_deg = degrees_of((trace - 1.0) / 2.0).mean().item<double>();
  out.centre = (ca - cb).norm(2, 1).mean().item<double>();
  // Camera-frame directions R^T (p - c): (N,P,3).
  const auto p = points.to(torch::kDouble);
  const auto da = torch::matmul(p.unsqueeze(0) - ca.unsqueeze(1), ra);
  const auto db = torch::matmul(p.unsqueeze(0) - cb.unsqueeze(1), rb);
  const auto cosine = (da * db).sum(-1) / (da.norm(2, -1) * db.norm(2, -1));
  out.reprojection_deg = degrees_of(cosine).mean().item<double>();
  return out;
}

torch::Tensor align_poses_rigid(const torch::Tensor& est, const torch::Tensor& truth) {
  TORCH_CHECK(est.dim() == 3 && est.size(1) >= 3 && est.size(2) == 4 && truth.sizes() == est.sizes() && est.size(0) > 0,
              "align_poses_rigid: est and truth must be the same (N,3,4) or (N,4,4), N > 0");
  const auto ca = centres(est), cb = centres(truth);
  const auto ma = ca.mean(0), mb = cb.mean(0);
  // Kabsch: H = sum (a - ma)(b - mb)^T = U S V^T, R = V diag(1, 1, det(V U^T)) U^T.
  const auto h = torch::matmul((ca - ma).t(), cb - mb);
  const auto [u, s, vh] = torch::linalg_svd(h);
  const auto v = vh.t();
  auto d = torch::ones({3}, torch::kDouble);
  d[2] = torch::det(torch::matmul(v, u.t())).sign();
  const auto r = torch::matmul(torch::matmul(v, torch::diag(d)), u.t());
  const auto t = mb - torch::matmul(r, ma);
  auto out = torch::empty({est.size(0), 3, 4}, torch::kDouble);
  out.slice(2, 0, 3).copy_(torch::matmul(r, rotations(est)));
  out.select(2, 3).copy_(torch::matmul(ca, r.t()) + t);
  return out;
}

torch::Tensor box_lattice(const torch::Tensor& lo, const torch::Tensor& hi) {
  const auto l = lo.to(torch::kDouble).reshape({3}), h = hi.to(torch::kDouble).reshape({3});
  const auto f = torch::tensor({0.0, 0.5, 1.0}, torch::kDouble);
  const auto axes =
      torch::meshgrid({l[0] + f * (h[0] - l[0]), l[1] + f * (h[1] - l[1]), l[2] + f * (h[2] - l[2])}, "ij");
  return torch::stack({axes[0].reshape({-1}), axes[1].reshape({-1}), axes[2].reshape({-1})}, 1);
}

}  // namespace ablenerf
