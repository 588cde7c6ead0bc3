#pragma once
// Stage 1 (docs/MODEL.md, section 1): a conical frustum [t0, t1] along a ray -> a Gaussian with diagonal
// covariance, in mip-NeRF's numerically stable form (mid-point mu and half-width h instead of
// differences of t^3 and t^5, which cancel catastrophically for short intervals in float32).
#include <torch/torch.h>

#include "data/rays.h"

namespace ablenerf {

// Moments of the frustum along the ray: distribution over t with density ~ t^2 on [t0, t1],
// and the variance of one perpendicular coordinate of a disc of radius r * t.
struct FrustumMoments {
  torch::Tensor t_mean;  // E[t]
  torch::Tensor t_var;   // Var[t]
  torch::Tensor r_var;   // r^2 E[t^2] / 4 (per perpendicular axis)
};

// The middles of the intervals between consecutive fence-posts (..., N+1) -> (..., N).
torch::Tensor interval_middles(const torch::Tensor& fence_posts);

// t0, t1: (B,S) interval ends; radius: (B,1) cone radius at t = 1 (broadcasts).
FrustumMoments conical_frustum_moments(const torch::Tensor& t0, const torch::Tensor& t1, const torch::Tensor& radius);

// A batch of axis-aligned Gaussians. mean, cov: (B,S,3) (cov holds the diagonal).
struct Gaussians {
  torch::Tensor mean, cov;
};

// Lifts the moments to 3-D along unnormalised directions: mean = o + d t_mean,
// cov_c = t_var d_c^2 + r_var (1 - d_c^2 / |d|^2). origins, directions: (B,3).
Gaussians lift_gaussian(const torch::Tensor& origins, const torch::Tensor& directions, const FrustumMoments& m);

// Fence-posts t (B,S+1) -> the S interval Gaussians of each ray.
Gaussians cast_intervals(const torch::Tensor& t, const Rays& rays);

}  // namespace ablenerf
