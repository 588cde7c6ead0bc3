#pragma once
// Stage 1b (unbounded scenes only; data.scene = "unbounded"): mip-NeRF 360's scene contraction
// applied to the frustum Gaussians before the IPE, and the spacing of samples along a ray that goes
// with it. The ABLE transformer, masks, LE and recipe are untouched: only where the samples lie and
// how they are encoded change.
//
//   contract(x) = x                          for |x| <= 1
//               = (2 - 1/|x|) x / |x|        for |x| > 1     (everything inside radius 2)
//
// A Gaussian (mean m, covariance S) maps to (contract(m), J S J^T), J the Jacobian of contract at m
// (mip-NeRF 360's linearisation). The IPE reads only the diagonal of a covariance, so only
// diag(J S J^T) is formed, exactly, from the frustum's full covariance
//   S = t_var d d^T + r_var (I - d d^T / |d|^2)
// (the diagonal alone would not be enough: J mixes the axes).
#include <torch/torch.h>

#include "data/rays.h"
#include "model/frustum.h"

namespace ablenerf {

// Contracted means and the diagonals of the contracted covariances. mean: (B,S,3) lifted means;
// directions (B,3) the rays' unnormalised directions; moments from conical_frustum_moments.
Gaussians contract_gaussians(const torch::Tensor& mean, const torch::Tensor& directions, const FrustumMoments& m);

// The interval Gaussians of fence posts t (B,S+1) along `rays`, lifted and contracted: the
// unbounded scene's counterpart of cast_intervals (model/frustum.h).
Gaussians contract_intervals(const torch::Tensor& t, const Rays& rays);

// The point map alone (B,...,3), for tests and for drawing where samples land.
torch::Tensor contract_points(const torch::Tensor& x);

// Unbounded sampling: normalised fence-posts s in [0, 1] -> depths t. The first half of s is
// linear in depth from `near` to `pivot` (the cameras' sphere: max(1, 2 near) in scene units), the
// second half linear in disparity from `pivot` to `far` (nerfstudio's piecewise linear/disparity
// spacing: a uniform grid in the contracted space's radius is close to this, and the inverse-CDF
// resampling works on s, so fine samples do not pile into the huge far intervals).
torch::Tensor unbounded_depths(const torch::Tensor& s, double near, double far);

}  // namespace ablenerf
