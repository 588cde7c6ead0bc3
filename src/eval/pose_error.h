#pragma once
// How far estimated cameras are from the true ones (`ablenerf metrics --cameras`; docs/MODEL.md,
// "Camera refinement"): the mean rotation error, the mean centre error, and the reprojection error,
// the mean angle between the directions in which an estimated camera and its true one see a set of
// scene points (what misplaces the scene in the photos; rotation and shift trade against each other
// in it as they do in the images).
//
// A radiance field trained on cameras that all share one rigid motion learns the same images in a
// moved frame: that common part no photo can reveal, and refinement leaves it where the given poses
// had it. BARF (Lin et al. 2021, section 4) therefore scores refined poses after aligning them to the
// truth with a Procrustes fit of the camera centres; pose_errors reports both, as given and aligned.
#include <torch/torch.h>

#include <string>

namespace ablenerf {

struct PoseErrors {
  double rotation_deg = 0;      // mean angle of R_est^T R_true
  double centre = 0;            // mean distance between the centres, in scene units
  double reprojection_deg = 0;  // mean over cameras and points of the angle between the viewing directions
};

// Mean errors of `est` against `truth` (N,3,4 or N,4,4 camera-to-world, OpenGL axes; float64 used),
// the reprojection over `points` (P,3) (points behind a camera count as they are: the angle between
// the two directions).
PoseErrors pose_errors(const torch::Tensor& est, const torch::Tensor& truth, const torch::Tensor& points);

// `est` moved by the one rigid motion x -> R x + t that takes its camera centres closest to truth's in
// squared distance (Kabsch's solution, a proper rotation), applied to whole cameras: (N,3,4). Fewer
// than three cameras, or centres on a line: the rotation that best fits what they fix (the SVD's
// least-squares solution).
torch::Tensor align_poses_rigid(const torch::Tensor& est, const torch::Tensor& truth);

// A lattice of 3 x 3 x 3 points (27,3) spanning the box [lo, hi] (each (3,)).
torch::Tensor box_lattice(const torch::Tensor& lo, const torch::Tensor& hi);

}  // namespace ablenerf
