#pragma once
// Geometry against a known surface: the spheres of a scene made by `ablenerf synth` (its
// scene.json) are known exactly, so exported points or a mesh (sampled uniformly on its triangles)
// can be scored as multi-view stereo benchmarks do (Knapitsch et al. 2017, Tanks and Temples):
// accuracy = each exported point's distance to the true surface, completeness = each true surface
// sample's distance to the nearest exported point, precision / recall = their shares within tau,
// F-score = their harmonic mean, Chamfer = the mean of the two mean distances. Truth samples are
// kept only where some camera of the capture sees them (the surface facing the camera and no sphere
// in the way): a surface no camera saw cannot be asked for.
#include <torch/torch.h>

#include <array>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "data/capture.h"
#include "synth/scene_truth.h"

namespace ablenerf {

// Evenly spread samples (golden-angle spiral) on each sphere, `per_sphere` each, kept where one of
// `eyes` (M,3) sees them; (K,3) float64 and the index of each sample's sphere (K).
std::pair<torch::Tensor, torch::Tensor> visible_sphere_samples(const std::vector<synth::SphereTruth>& spheres,
                                                               const torch::Tensor& eyes, int64_t per_sphere);

// Scores `points` (N,3) against the spheres at threshold `tau`: {"all": {...}, "<sphere name>": {...}},
// each with points, samples, accuracy_mean, completeness_mean, chamfer, precision, recall, fscore.
// A point counts for the sphere whose surface is nearest to it.
nlohmann::json score_against_spheres(const torch::Tensor& points, const std::vector<synth::SphereTruth>& spheres,
                                     const torch::Tensor& eyes, double tau, int64_t per_sphere = 20000);

// Points known to lie on the true surface against exported geometry, for captures without an
// exact scene: a COLMAP capture's sparse points, each triangulated from several photos. For each
// reference point inside the geometry's bounding box (grown by 5% of its diagonal on every side: a
// point outside lies where nothing was exported, e.g. the far background an export's crop leaves
// out, and is not asked for), the distance to the nearest point of `geometry` (N,3; a mesh sampled
// on its surface, so distances include up to half the sample spacing). Returns {"reference_points",
// "inside", "tau", "distance_median", "distance_mean", "within_tau"} (the share of the inside points
// within tau; null figures when none is inside).
nlohmann::json score_reference_points(const torch::Tensor& geometry, const torch::Tensor& reference, double tau);

// The pixels of a capture's depth maps (nerf_synthetic's test views, a synth scene's;
// data/depth_file.h): every `view_step`-th frame of `split` that has one, every `pixel_step`-th
// pixel along both axes. Their rays (data/rays.h: directions with camera-space z = -1) in the
// capture's coordinates, (N,3) each, and their depth along them (N), 0 where nothing was hit. 8-bit
// maps hold depth to within half a step (Blender: 0.016).
struct DepthTruth {
  torch::Tensor origins, directions, depth;
  // The views they came from, for rendering geometry the same way: each one's camera-to-world
  // (3,4), camera, and which of its pixels (flat indices, row-major) are in the rows above.
  std::vector<std::pair<torch::Tensor, Intrinsics>> cameras;
  std::vector<torch::Tensor> pixels;
};
DepthTruth depth_truth(const CaptureSplit& split, int64_t view_step, int64_t pixel_step);
// The points where they hit something, origin + depth x direction: (M,3) float64.
torch::Tensor depth_truth_points(const DepthTruth& truth);

// A depth map of the geometry (e.g. a mesh's from the truth's cameras: fuse.h, mesh_depth_maps)
// against the truth's, both (N) in the same units; the truth's 0 and the geometry's non-finite or
// 0 mean nothing there. {"pixels", "surface_pixels" (the truth's), "hit_share" (of those, where the
// geometry has a surface too), "false_surface_share" (of the truth's background, where it has one),
// "depth_mae", "depth_median" (|error| where both have a surface; null when nowhere)}.
nlohmann::json score_depth_against_truth(const torch::Tensor& depth, const torch::Tensor& truth);

// Geometry against dense truth points, as score_against_spheres scores spheres: accuracy = each
// geometry point's distance to the nearest truth point, completeness = each truth point's to the
// nearest geometry point; {"points", "samples", "accuracy_mean", "completeness_mean", "chamfer",
// "precision", "recall", "fscore", "tau"}. Truth covers what its views saw: geometry elsewhere (a
// floor under the object no view looks at) counts against accuracy.
nlohmann::json score_against_truth_points(const torch::Tensor& geometry, const torch::Tensor& truth, double tau);

// A default threshold for score_reference_points: 1% of the diagonal of the box that holds the
// central 98% of `points` (N,3) along each axis (sparse points have stray far ones).
double reference_tau(const torch::Tensor& points);

}  // namespace ablenerf
