#include "model/contraction.h"

#include "kernels/sample_encoding_cpu.h"

#include <algorithm>

namespace ablenerf {

torch::Tensor contract_points(const torch::Tensor& x) {
  const auto r = x.norm(2, -1, /*keepdim=*/true).clamp_min(kContractRadiusEps);
  return torch::where(r <= 1, x, (2 - 1 / r) * x / r);
}

Gaussians contract_gaussians(const torch::Tensor& mean, const torch::Tensor& directions, const FrustumMoments& m) {
  // S = a d d^T + b I with a = t_var - r_var / |d|^2, b = r_var (per sample).
  const auto d = directions.unsqueeze(1);  // (B,1,3)
  const auto d2 = (d * d).sum(-1);         // (B,1)
  const auto b = m.r_var;                  // (B,S)
  const auto a = m.t_var - m.r_var / d2;   // (B,S)
  // Inside the unit ball J = I: diag S = a d_c^2 + b.
  // Outside, with r = |x|, f(r) = (2 - 1/r) / r: J = f I + f'(r)/r x x^T, f' = (2/r^3 - 2/r^2).
  const auto r = mean.norm(2, -1, /*keepdim=*/true).clamp_min(kContractRadiusEps);  // (B,S,1)
  const auto outside = r > 1;
  const auto f = torch::where(outside, (2 - 1 / r) / r, torch::ones_like(r));
  const auto g = torch::where(outside, (2 / (r * r * r) - 2 / (r * r)) / r, torch::zeros_like(r));  // f'(r) / r
  // J = f I + g x x^T is symmetric. Rows: J_c. = f e_c + g x_c x.
  //   (J d)_c = f d_c + g x_c (x . d);   sum_j J_cj^2 = f^2 + 2 f g x_c^2 + g^2 x_c^2 |x|^2.
  const auto xd = (mean * d).sum(-1, /*keepdim=*/true);  // (B,S,1)
  const auto jd = f * d + g * mean * xd;                 // (B,S,3)
  const auto x2 = mean * mean;
  const auto jj = f * f + 2 * f * g * x2 + g * g * x2 * (r * r);
  Gaussians out;
  out.mean = contract_points(mean);
  out.cov = b.unsqueeze(-1) * jj + a.unsqueeze(-1) * jd * jd;
  return out;
}

Gaussians contract_intervals(const torch::Tensor& t, const Rays& rays) {
  const int64_t n = t.size(-1);
  const auto m = conical_frustum_moments(t.slice(-1, 0, n - 1), t.slice(-1, 1, n), rays.radii);
  const auto mean = rays.origins.unsqueeze(1) + rays.directions.unsqueeze(1) * m.t_mean.unsqueeze(-1);
  return contract_gaussians(mean, rays.directions, m);
}

torch::Tensor unbounded_depths(const torch::Tensor& s, double near, double far) {
  const double pivot = std::max(1.0, 2 * near);
  const auto lin = near + (pivot - near) * (2 * s);
  // Disparity from 1/pivot (s = 0.5) to 1/far (s = 1).
  const auto u = (2 * s - 1).clamp(0, 1);
  const auto disp = (1 / pivot) + u * (1 / far - 1 / pivot);
  return torch::where(s <= 0.5, lin, 1 / disp);
}

}  // namespace ablenerf
