#include "model/frustum.h"

#include "kernels/sample_encoding_cpu.h"

namespace ablenerf {

FrustumMoments conical_frustum_moments(const torch::Tensor& t0, const torch::Tensor& t1, const torch::Tensor& radius) {
  const auto mu = 0.5 * (t0 + t1);
  const auto h = 0.5 * (t1 - t0);
  const auto mu2 = mu * mu, h2 = h * h;
  const auto denom = 3.0 * mu2 + h2;
  FrustumMoments m;
  m.t_mean = mu + 2.0 * mu * h2 / denom;
  m.t_var = h2 / 3.0 - (4.0 / 15.0) * (h2 * h2 * (12.0 * mu2 - h2)) / (denom * denom);
  m.r_var = radius * radius * (mu2 / 4.0 + (5.0 / 12.0) * h2 - (4.0 / 15.0) * (h2 * h2) / denom);
  return m;
}

Gaussians lift_gaussian(const torch::Tensor& origins, const torch::Tensor& directions, const FrustumMoments& m) {
  const auto d = directions.unsqueeze(1);  // (B,1,3)
  const auto d2 = d * d;
  const auto perp = 1.0 - d2 / (d2.sum(-1, /*keepdim=*/true) + kFrustumDirNormEps);
  Gaussians g;
  g.mean = origins.unsqueeze(1) + d * m.t_mean.unsqueeze(-1);
  g.cov = m.t_var.unsqueeze(-1) * d2 + m.r_var.unsqueeze(-1) * perp;
  return g;
}

Gaussians cast_intervals(const torch::Tensor& t, const Rays& rays) {
  const int64_t n = t.size(-1);
  const auto m = conical_frustum_moments(t.slice(-1, 0, n - 1), t.slice(-1, 1, n), rays.radii);
  return lift_gaussian(rays.origins, rays.directions, m);
}

torch::Tensor interval_middles(const torch::Tensor& fence_posts) {
  const int64_t n = fence_posts.size(-1) - 1;
  return 0.5 * (fence_posts.slice(-1, 0, n) + fence_posts.slice(-1, 1, n + 1));
}

}  // namespace ablenerf
