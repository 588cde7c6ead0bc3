#pragma once
// The lens models behind the camera interface (camera.h), batched for ray generation: each maps
// undistorted normalised coordinates to distorted ones (distort) and back (undistort, an
// iterative inverse as COLMAP and nerfstudio do: no image is ever resampled). Everything runs in
// float64 with a fixed number of iterations and no read-back to the host, so a batch costs the same
// whatever its content and can run inside a captured CUDA graph.
#include <torch/torch.h>

#include "data/rays.h"

namespace ablenerf {

// xy: (B,2) float64 normalised coordinates (OpenCV axes); cams: one row per point (CameraTable::
// index); only the lens coefficients are used. Points of a pinhole row are returned unchanged.
torch::Tensor distort_points(const CameraTable& cams, const torch::Tensor& xy);
torch::Tensor undistort_points(const CameraTable& cams, const torch::Tensor& xy_distorted);

// The derivative of the undistorted point with respect to the distorted y coordinate, at the
// undistorted points `xy` (B,2): the image of one pixel step down (divided by fy) in the plane of
// the ray directions, from which the cone radius follows. (0, 1) for a pinhole. Central
// differences of distort_points (float64, step 1e-6) and the inverse of that 2x2 Jacobian.
torch::Tensor undistorted_step_y(const CameraTable& cams, const torch::Tensor& xy);

// One file per model (lens_radial_tangential.cpp, lens_fisheye.cpp); coeffs (B, kLensCoeffs).
torch::Tensor radial_tangential_distort(const torch::Tensor& xy, const torch::Tensor& coeffs);
torch::Tensor radial_tangential_undistort(const torch::Tensor& xy_distorted, const torch::Tensor& coeffs);
torch::Tensor fisheye_distort(const torch::Tensor& xy, const torch::Tensor& coeffs);
torch::Tensor fisheye_undistort(const torch::Tensor& xy_distorted, const torch::Tensor& coeffs);

// Newton iterations of the inverses: enough to reach float64 round-off for real lenses.
constexpr int kLensNewtonIterations = 20;

// Largest angle from the optical axis a fisheye ray may have: the ray generator puts directions on
// the plane z = -1, which reaches only angles below 90 degrees.
constexpr double kFisheyeMaxTheta = 1.5533430342749532;  // 89 degrees

}  // namespace ablenerf
