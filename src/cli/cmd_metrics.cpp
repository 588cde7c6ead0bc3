// `ablenerf metrics`: PSNR, SSIM and LPIPS of one image pair, printed as one JSON object.
//
// Images are read with read_rgb_for_metrics: RGBA is composited on white (the Blender dataset
// convention), greyscale is replicated to RGB. JSON has no infinity, so identical images print
// "psnr": null with a "psnr_note"; "mse" is always printed. Without LPIPS weights (no
// --lpips-weights, no $ABLENERF_LPIPS_WEIGHTS, no shared weights beside the repository) or for
// images smaller than AlexNet accepts, "lpips" is null and "lpips_note" says why.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>

#include "cli/command.h"
#include "cli/common.h"
#include "eval/lpips.h"
#include "eval/metrics.h"
#include "eval/pose_error.h"
#include "data/transforms_json.h"  // metrics --cameras reads camera-to-world matrices as the formats do
#ifdef ABLENERF_HAVE_GEOMETRY
#include "data/capture.h"
#include "data/dataset.h"
#include "geometry/fuse.h"
#include "geometry/surface_score.h"
#endif
#include "util/errors.h"
#include "util/json_file.h"
#include "synth/scene_truth.h"
#include "eval/eval_config.h"

namespace ablenerf::cli {
namespace cmd_metrics {

struct MetricsArgs {
  std::string ref, img, lpips_weights, ssim = "standard";
  std::string poses;            // estimated cameras against a synth scene's true training cameras
  std::string geometry, truth;  // geometry against a synth scene's spheres or a capture's sparse points
  double tau = 0;
  int64_t samples = 200000;
};

// Dense truth from depth maps (geometry/surface_score.h, depth_truth): views and pixels taken.
constexpr int64_t kTruthViews = 20;
constexpr int kTruthSide = 200;

// --geometry FILE --truth DATA: the file's points (a mesh sampled on its surface) against the
// spheres of DATA/scene.json, seen from DATA's cameras (geometry/surface_score.h); or, for a
// capture without a scene.json, the points of its depth maps (nerf_synthetic's test views) scored
// as the spheres are, else its sparse points (COLMAP) and their distances to the geometry; all in
// the capture's own frame (export's default --frame).
void run_geometry(const MetricsArgs& a) {
#ifdef ABLENERF_HAVE_GEOMETRY
  if (!std::filesystem::exists(std::filesystem::path(a.truth) / "scene.json")) {
    const Capture capture = read_capture(a.truth, {}, 1);
    for (const CaptureSplit& split : capture.splits) {
      if (split.frames.empty() || !std::all_of(split.frames.begin(), split.frames.end(),
                                               [](const CaptureFrame& f) { return !f.depth.empty(); }))
        continue;
      // About kTruthViews views of ~kTruthSide pixels across: ~10^5 truth points on lego.
      const int64_t views = static_cast<int64_t>(split.frames.size());
      const int64_t view_step = std::max<int64_t>(1, views / kTruthViews);
      const int64_t pixel_step = std::max<int64_t>(1, split.frames.front().camera.width / kTruthSide);
      const DepthTruth truth = depth_truth(split, view_step, pixel_step);
      const auto truth_points = depth_truth_points(truth);
      const double tau = a.tau > 0 ? a.tau : reference_tau(truth_points);
      const PointSet pts = read_geometry_points(a.geometry, a.samples);
      auto out = score_against_truth_points(pts.xyz, truth_points, tau);
      // A mesh is also seen from the truth's cameras: its depth maps against theirs (pinhole
      // cameras: nerf_synthetic's and synth's).
      const bool pinhole =
          std::none_of(truth.cameras.begin(), truth.cameras.end(), [](const auto& c) { return c.second.distorted(); });
      const auto maps = pinhole ? mesh_depth_maps(a.geometry, truth.cameras) : std::vector<torch::Tensor>{};
      if (!maps.empty()) {
        std::vector<torch::Tensor> seen;
        for (size_t v = 0; v < maps.size(); ++v) seen.push_back(maps[v].reshape({-1}).index_select(0, truth.pixels[v]));
        out["mesh_depth"] = score_depth_against_truth(torch::cat(seen), truth.depth);
      }
      out["file"] = a.geometry;
      out["truth"] = capture.format + " depth maps: " + std::to_string((views + view_step - 1) / view_step) + " " +
                     split.name + " views, every " + std::to_string(pixel_step) + " pixels";
      std::cout << out.dump(2) << std::endl;
      return;
    }
    if (capture.points.empty())
      throw InputError(a.truth, "scene.json",
                       "missing, and the capture has no depth maps or sparse points: --truth takes a scene made by "
                       "`ablenerf synth`, a Blender scene with depth maps or a COLMAP capture");
    auto ref = torch::empty({static_cast<int64_t>(capture.points.size()), 3}, torch::kDouble);
    auto acc = ref.accessor<double, 2>();
    for (size_t i = 0; i < capture.points.size(); ++i)
      for (int k = 0; k < 3; ++k) acc[static_cast<int64_t>(i)][k] = capture.points[i][k];
    const double tau = a.tau > 0 ? a.tau : reference_tau(ref);
    const PointSet pts = read_geometry_points(a.geometry, a.samples);
    auto out = score_reference_points(pts.xyz, ref, tau);
    out["file"] = a.geometry;
    out["truth"] = capture.format + " sparse points";
    std::cout << out.dump(2) << std::endl;
    return;
  }
  const auto spheres = synth::read_scene_spheres(a.truth + "/scene.json");
  const CameraList cams = capture_cameras(a.truth, SceneFrame{}, 1);
  const auto eyes = cams.c2w.select(2, 3);  // camera centres (N,3)
  // tau: 1% of the size of the objects (their bounding box's diagonal) unless given.
  double lo[3] = {1e300, 1e300, 1e300}, hi[3] = {-1e300, -1e300, -1e300};
  for (const auto& s : spheres)
    for (size_t i = 0; i < 3; ++i)
      lo[i] = std::min(lo[i], s.centre[i] - s.radius), hi[i] = std::max(hi[i], s.centre[i] + s.radius);
  const double size = std::sqrt((hi[0] - lo[0]) * (hi[0] - lo[0]) + (hi[1] - lo[1]) * (hi[1] - lo[1]) +
                                (hi[2] - lo[2]) * (hi[2] - lo[2]));
  const double tau = a.tau > 0 ? a.tau : 0.01 * size;
  const PointSet pts = read_geometry_points(a.geometry, a.samples);
  auto out = score_against_spheres(pts.xyz, spheres, eyes, tau);
  out["file"] = a.geometry;
  out["scene_size"] = size;
  std::cout << out.dump(2) << std::endl;
#else
  throw EnvironmentError("metrics", "this build has no geometry scoring",
                         "install Open3D: apt-get install libopen3d-dev");
#endif
}

// A (3,4) camera-to-world in double precision, checked as the transforms formats check theirs.
torch::Tensor pose_of(const nlohmann::json& m, const std::string& file, const std::string& field) {
  double a[3][4];
  parse_pose_matrix(m, file, field, a);
  return torch::from_blob(a, {3, 4}, torch::kDouble).clone();
}

nlohmann::json errors_json(const PoseErrors& e) {
  return {{"rotation_deg", e.rotation_deg}, {"centre", e.centre}, {"reprojection_deg", e.reprojection_deg}};
}

// --cameras FILE --truth DATA: FILE's frames (a transforms.json: `export --cameras`, or the capture's
// own transforms_train.json for the given poses), in order, against the true training cameras that
// `synth --pose-noise-deg` records in DATA/scene.json; the reprojection over a 3x3x3 lattice spanning
// the scene's objects (eval/pose_error.h). As given, and after the rigid alignment of the centres.
void run_poses(const MetricsArgs& a) {
  const std::string scene_file = (std::filesystem::path(a.truth) / "scene.json").string();
  if (!std::filesystem::exists(scene_file))
    throw InputError(scene_file, "", "missing: --cameras scores against a scene made by `ablenerf synth`");
  const auto scene = read_json_file(scene_file);
  if (!scene.contains("train_view_truth") || !scene["train_view_truth"].is_array())
    throw InputError(scene_file, "train_view_truth",
                     "missing: the scene has no true training cameras (made without --pose-noise-deg?)");
  const auto est_json = read_json_file(a.poses);
  if (!est_json.contains("frames") || !est_json["frames"].is_array())
    throw InputError(a.poses, "frames", "missing (a transforms.json, e.g. written by `export --cameras`)");
  const auto& truth_views = scene["train_view_truth"];
  const auto& frames = est_json["frames"];
  if (frames.size() != truth_views.size() || frames.empty())
    throw InputError(a.poses, "frames",
                     "has " + std::to_string(frames.size()) + " cameras, the scene's training views " +
                         std::to_string(truth_views.size()));
  std::vector<torch::Tensor> est, truth;
  for (size_t i = 0; i < frames.size(); ++i) {
    const std::string at = "[" + std::to_string(i) + "]";
    const auto field = [](const nlohmann::json& o, const char* key) {
      return o.is_object() && o.contains(key) ? o[key] : nlohmann::json();
    };
    est.push_back(pose_of(field(frames[i], "transform_matrix"), a.poses, "frames" + at + ".transform_matrix"));
    truth.push_back(pose_of(field(truth_views[i], "true_transform_matrix"), scene_file,
                            "train_view_truth" + at + ".true_transform_matrix"));
  }
  // The objects' box: the scene's spheres.
  auto lo = torch::full({3}, 1e300, torch::kDouble), hi = torch::full({3}, -1e300, torch::kDouble);
  for (const auto& s : synth::scene_spheres(scene, scene_file)) {
    const auto c = torch::tensor({s.centre[0], s.centre[1], s.centre[2]}, torch::kDouble);
    lo = torch::minimum(lo, c - s.radius);
    hi = torch::maximum(hi, c + s.radius);
  }
  const auto e = torch::stack(est), t = torch::stack(truth), points = box_lattice(lo, hi);
  const auto aligned = align_poses_rigid(e, t);
  nlohmann::json out;
  out["cameras"] = frames.size();
  out["as_given"] = errors_json(pose_errors(e, t, points));
  out["aligned"] = errors_json(pose_errors(aligned, t, points));
  out["aligned_note"] =
      "after the one rigid motion that takes the cameras' centres closest to the truth's (Kabsch), as BARF scores "
      "refined poses: the motion common to all cameras is one no photo reveals";
  out["points"] = "3x3x3 lattice over the objects' bounding box";
  out["file"] = a.poses;
  std::cout << out.dump(2) << std::endl;
}

std::string size_str(const torch::Tensor& im) { return std::to_string(im.size(1)) + "x" + std::to_string(im.size(0)); }

void run(const MetricsArgs& a) {
  if (!a.poses.empty()) {
    if (a.truth.empty()) throw InputError("metrics", "--truth", "--cameras needs --truth DATA (a synth scene)");
    run_poses(a);
    return;
  }
  if (!a.geometry.empty() || !a.truth.empty()) {
    if (a.geometry.empty() || a.truth.empty())
      throw InputError("metrics", "--geometry",
                       "give both --geometry FILE and --truth DATA (a synth scene or a COLMAP capture)");
    run_geometry(a);
    return;
  }
  if (a.ref.empty() || a.img.empty()) throw InputError("metrics", "--ref", "give --ref A.png and --img B.png");
  const SsimVariant variant = parse_ssim_variant(a.ssim, "metrics", "--ssim");
  const torch::Tensor ref = read_rgb_for_metrics(a.ref);
  const torch::Tensor img = read_rgb_for_metrics(a.img);
  if (ref.sizes() != img.sizes())
    throw InputError(
        a.img, "",
        "is " + size_str(img) + " but " + a.ref + " is " + size_str(ref) + "; the images must have the same size");
  if (variant == SsimVariant::Standard && (ref.size(0) < kSsimWindow || ref.size(1) < kSsimWindow))
    throw InputError(a.ref, "",
                     "standard SSIM needs images of at least " + std::to_string(kSsimWindow) + "x" +
                         std::to_string(kSsimWindow) + " (use --ssim release)");

  nlohmann::json out;
  const double p = psnr(img, ref);
  out["mse"] = mse(img, ref);
  if (std::isinf(p)) {
    out["psnr"] = nullptr;
    out["psnr_note"] = "identical images (MSE 0): PSNR is +infinity";
  } else {
    out["psnr"] = p;
  }
  out["ssim"] = ssim(img, ref, variant);
  out["ssim_variant"] = name_of(variant);

  const std::string weights = a.lpips_weights.empty() ? default_lpips_weights_path() : a.lpips_weights;
  if (weights.empty()) {
    out["lpips"] = nullptr;
    out["lpips_note"] = "no LPIPS weights: pass --lpips-weights FILE or set ABLENERF_LPIPS_WEIGHTS";
  } else if (ref.size(0) < Lpips::kMinSide || ref.size(1) < Lpips::kMinSide) {
    out["lpips"] = nullptr;
    out["lpips_note"] = "images smaller than " + std::to_string(Lpips::kMinSide) + "x" +
                        std::to_string(Lpips::kMinSide) + " are too small for LPIPS (AlexNet)";
  } else {
    out["lpips"] = Lpips(weights).distance(img, ref);
    out["lpips_net"] = "alex-v0.1";
  }
  std::cout << out.dump(2) << std::endl;
}

void setup(CLI::App& app) {
  auto a = std::make_shared<MetricsArgs>();
  app.add_option("--ref", a->ref, "Reference (ground-truth) PNG");
  app.add_option("--img", a->img, "Image to score (PNG, same size as --ref)");
  app.add_option("--cameras", a->poses,
                 "Cameras (a transforms.json: `export --cameras`) to score against --truth's true training cameras "
                 "(a synth scene made with --pose-noise-deg)");
  add_old_spelling(app, "--poses", "--cameras", a->poses);
  app.add_option("--geometry", a->geometry, "Points or a mesh (.ply, .obj, .glb) to score against --truth");
  app.add_option("--truth", a->truth,
                 "A scene made by `ablenerf synth` (its scene.json and cameras), a Blender scene with depth maps "
                 "(nerf_synthetic's test views), or a COLMAP capture (its sparse points)");
  app.add_option("--tau", a->tau,
                 "Distance threshold (default: 1% of the objects' size, or of the sparse points' central 98%)");
  app.add_option("--samples", a->samples, "Points sampled on a mesh's surface")->capture_default_str();
  app.add_option("--lpips-weights", a->lpips_weights,
                 "LPIPS AlexNet v0.1 weights (default: $ABLENERF_LPIPS_WEIGHTS or ../shared/weights)");
  app.add_option("--ssim", a->ssim, "SSIM variant: standard (mip-NeRF, valid) or release (authors', zero-padded)")
      ->capture_default_str();
  add_json_flag(app);
  app.callback([a] { run(*a); });
}

}  // namespace cmd_metrics
ABLENERF_COMMAND("metrics", 80, "PSNR, SSIM and LPIPS of one image pair; or geometry or cameras against a synth scene",
                 cmd_metrics::setup);
}  // namespace ablenerf::cli
