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

namespace ablenerf {

struct SphereTruth {
  std::string name, material;
  std::array<double, 3> centre{};
  double radius = 0;
};

// The spheres of a synth scene.json ("objects" of shape "sphere"); InputError naming the file and
// field otherwise.
std::vector<SphereTruth> read_scene_spheres(const std::string& scene_json);

// Evenly spread samples (golden-angle spiral) on each sphere, `per_sphere` each, kept where one of
// `eyes` (M,3) sees them; (K,3) float64 and the index of each sample's sphere (K).
std::pair<torch::Tensor, torch::Tensor> visible_sphere_samples(const std::vector<SphereTruth>& spheres,
                                                               const torch::Tensor& eyes, int64_t per_sphere);

// Scores `points` (N,3) against the spheres at threshold `tau`: {"all": {...}, "<sphere name>": {...}},
// each with points, samples, accuracy_mean, completeness_mean, chamfer, precision, recall, fscore.
// A point counts for the sphere whose surface is nearest to it.
nlohmann::json score_against_spheres(const torch::Tensor& points, const std::vector<SphereTruth>& spheres,
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

// A default threshold for score_reference_points: 1% of the diagonal of the box that holds the
// central 98% of `points` (N,3) along each axis (sparse points have stray far ones).
double reference_tau(const torch::Tensor& points);

}  // namespace ablenerf
