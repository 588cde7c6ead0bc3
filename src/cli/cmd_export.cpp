// `ablenerf export`: writes every model parameter as a torch.load-able name -> tensor
// dictionary (save_weights format, names in docs/weights.md), either from a run folder
// (RUN/config.toml + RUN/weights.pt) or freshly initialised from a config; and, from a run, the
// scene as geometry: coloured points (--points) and a mesh (--mesh), geometry/export_geometry.h;
// and the training cameras as the run refined them (--cameras, train.camera_refine).
#include <torch/torch.h>

#include <cmath>
#include <iostream>
#include <nlohmann/json.hpp>

#include "cli/command.h"
#include "cli/common.h"
#include "data/capture.h"
#include "data/dataset.h"
#include "model/able_nerf.h"
#include "run/run_folder.h"
#include "util/errors.h"
#include "util/fs.h"
#ifdef ABLENERF_HAVE_GEOMETRY
#include "eval/report.h"
#include "geometry/export_geometry.h"
#include "eval/eval_config.h"
#include "model/model_config.h"
#endif

namespace ablenerf::cli {
namespace cmd_export {

constexpr int64_t kDefaultSeed = 4;  // the release's seed

struct ExportArgs {
  std::string run, out;
  int64_t seed = kDefaultSeed;
  ConfigOptions cfg;
  // Geometry.
  std::string poses;
  std::string points, mesh, method = "tsdf", crop, frame = "capture", device = "auto";
  int64_t num_points = 1'000'000, views = 48;
  int resolution = 0, max_side = 200;
  std::string mask = "alpha", depth = "auto";
  std::string preview;  // "" = RUN/geometry_preview.png; "none" = no picture
};

void run_export_weights(const ExportArgs& a) {
  const bool from_config = !a.cfg.config_path.empty() || !a.cfg.preset.empty();
  if (a.run.empty() == !from_config)
    throw InputError("export", "--run", "give exactly one of --run RUN, --config FILE or --preset NAME");
  if (!a.run.empty() && !a.cfg.sets.empty())
    throw InputError("export", "--set", "--set applies to --config or --preset only (a run's config is fixed)");
  Config c;
  if (!a.run.empty()) {
    c = Config::load(a.run + "/config.toml");
    c.validate();
  } else {
    c = resolve_config(a.cfg);
  }
  torch::manual_seed(static_cast<uint64_t>(a.seed));
  AbleNerf model(c.get<ModelConfig>());
  if (!a.run.empty()) load_weights(model, a.run + "/weights.pt");
  save_weights(model, a.out);
  nlohmann::json j;
  j["out"] = a.out;
  j["parameters"] = model->parameter_count();
  j["source"] = a.run.empty() ? "init(seed=" + std::to_string(a.seed) + ")" : a.run;
  std::cout << j.dump() << std::endl;
}

void run_geometry(const ExportArgs& a) {
  if (a.run.empty()) throw InputError("export", "--run", "--points and --mesh export a trained run: give --run RUN");
  if (a.method != "tsdf" && a.method != "poisson")
    throw InputError("export", "--method", "'" + a.method + "' (expected tsdf or poisson)");
  if (a.frame != "capture" && a.frame != "scene")
    throw InputError("export", "--frame", "'" + a.frame + "' (expected capture or scene)");
  if (a.mask != "alpha" && a.mask != "none")
    throw InputError("export", "--mask", "'" + a.mask + "' (expected alpha or none)");
  if (a.depth != "auto" && a.depth != "front" && a.depth != "mean")
    throw InputError("export", "--depth", "'" + a.depth + "' (expected auto, front or mean)");
  if (a.num_points < 1) throw InputError("export", "--num-points", "must be >= 1");
#ifdef ABLENERF_HAVE_GEOMETRY
  GeometryOptions o;
  o.points_path = a.points;
  o.mesh_path = a.mesh;
  o.num_points = a.num_points;
  o.resolution = a.resolution;
  o.method = a.method == "poisson" ? MeshMethod::Poisson : MeshMethod::Tsdf;
  if (!a.crop.empty()) o.crop = CropBox::parse(a.crop, "--crop");
  o.scene_frame = a.frame == "scene";
  o.views = a.views;
  o.max_side = a.max_side;
  o.alpha_mask = a.mask == "alpha";
  o.depth = a.depth == "mean" ? DepthEstimate::Mean : a.depth == "front" ? DepthEstimate::Front : DepthEstimate::Auto;
  o.device = parse_device(a.device);
  const RunFolder run = RunFolder::open(a.run);
  if (a.preview != "none") o.preview_path = a.preview.empty() ? run.path(kGeometryPreviewFile) : a.preview;
  o.chunk = run.config.get<EvalConfig>().chunk;
  const nlohmann::json result = export_geometry(run, o);
  // The run's report lists what was exported (RUN/exports.json).
  record_export(run, result);
  write_report(run);
  std::cout << result.dump() << std::endl;
#else
  throw EnvironmentError("export", "this build has no geometry export",
                         "install Open3D: apt-get install libopen3d-dev, then rebuild with scripts/setup.sh");
#endif
}

// The training cameras as the run refined them (model/camera_refine.h), in the capture's own
// coordinates, as a transforms.json that instant-ngp and nerfstudio read (and `ablenerf train`):
// each frame's full-size image and camera, its corrected camera-to-world, and the correction's
// angle (degrees) and shift (capture units).
void run_export_poses(const ExportArgs& a) {
  if (a.run.empty()) throw InputError("export", "--run", "--cameras exports a trained run's cameras: give --run RUN");
  const RunFolder run = RunFolder::open(a.run);
  AbleNerf model(run.config.get<ModelConfig>());
  load_weights(model, run.path("weights.pt"));
  CameraRefineImpl* refine = model->camera_refine();
  if (refine == nullptr)
    throw InputError(run.path("weights.pt"), "camera_refine.correction",
                     "the run did not refine its cameras (train with --set train.camera_refine=true)");
  const SceneFrame scene = run.scene();
  // The training split, full-size images: the photos the corrections belong to, in training order.
  const Capture capture = read_capture(run.data_dir, {"train"}, 1);
  const CaptureSplit* train = nullptr;
  for (const auto& s : capture.splits)
    if (s.name == "train") train = &s;
  if (train == nullptr || static_cast<int64_t>(train->frames.size()) != refine->cameras())
    throw InputError(run.path("weights.pt"), "camera_refine.correction",
                     std::to_string(refine->cameras()) + " cameras, but " + run.data_dir + " has " +
                         std::to_string(train ? train->frames.size() : 0) + " training images");
  std::vector<torch::Tensor> given;
  for (const auto& f : train->frames) {
    given.push_back(pose_tensor(scene.to_scene(f.pose)));
  }
  torch::NoGradGuard no_grad;
  const auto given_c2w = torch::stack(given).to(refine->parameter().dtype());
  refine->set_cameras(given_c2w);  // the gauge as training had it
  const auto corrected = refine->corrected(given_c2w).to(torch::kDouble);
  const auto correction = refine->correction().to(torch::kDouble);
  nlohmann::json out;
  out["frames"] = nlohmann::json::array();
  for (size_t i = 0; i < train->frames.size(); ++i) {
    const auto& f = train->frames[i];
    Pose34 p{};
    for (int k = 0; k < 12; ++k)
      p[static_cast<size_t>(k)] = corrected[static_cast<int64_t>(i)][k / 4][k % 4].item<float>();
    const Pose34 back = scene.to_capture(p);
    nlohmann::json m = nlohmann::json::array();
    for (int r = 0; r < 3; ++r) m.push_back({back[r * 4], back[r * 4 + 1], back[r * 4 + 2], back[r * 4 + 3]});
    m.push_back({0, 0, 0, 1});
    const auto c = correction[static_cast<int64_t>(i)];
    nlohmann::json fr;
    fr["file_path"] = f.image;
    fr["transform_matrix"] = m;
    const Intrinsics cam = refine->refined(f.camera);  // the refined focal length, if it learned one
    fr["fl_x"] = cam.fx, fr["fl_y"] = cam.fy, fr["cx"] = cam.cx, fr["cy"] = cam.cy;
    fr["w"] = f.camera.width, fr["h"] = f.camera.height;
    fr["refined_rotation_deg"] = c.slice(0, 0, 3).norm().item<double>() * 180.0 / M_PI;
    fr["refined_shift"] = c.slice(0, 3, 6).norm().item<double>() / scene.scale;
    out["frames"].push_back(fr);
  }
  out["refined_by"] = "ablenerf train.camera_refine, run " + a.run;
  if (refine->refines_focal()) out["refined_focal_scale"] = refine->focal_scale_value();
  write_file_atomic(a.poses, out.dump(2) + "\n");
  nlohmann::json j;
  j["poses"] = a.poses;
  j["cameras"] = train->frames.size();
  std::cout << j.dump() << std::endl;
}

void run_export(const ExportArgs& a) {
  if (!a.poses.empty()) {
    run_export_poses(a);
    if (a.points.empty() && a.mesh.empty() && a.out.empty()) return;
  }
  if (!a.points.empty() || !a.mesh.empty()) {
    if (!a.out.empty()) run_export_weights(a);
    run_geometry(a);
    return;
  }
  if (a.out.empty())
    throw InputError("export", "--out",
                     "give --out FILE.pt (weights), --points FILE.ply, --mesh FILE or --cameras FILE.json");
  run_export_weights(a);
}

void setup(CLI::App& app) {
  auto a = std::make_shared<ExportArgs>();
  app.add_option("--run", a->run, "Run folder holding config.toml and weights.pt");
  a->cfg.add_to(app, false);
  app.add_option("--seed", a->seed, "Initialisation seed with --config (default 4)");
  app.add_option("--out", a->out, "Output .pt file of the weights");
  app.add_option("--points", a->points, "Coloured points with normals from the run's depth, as FILE.ply");
  app.add_option("--mesh", a->mesh, "A mesh of the run's surfaces, as FILE.ply, .obj or .glb");
  app.add_option("--cameras", a->poses,
                 "The training cameras as refined by the run (train.camera_refine), as a transforms.json");
  add_old_spelling(app, "--poses", "--cameras", a->poses);
  app.add_option("--num-points", a->num_points, "Points kept at most, evenly thinned")->capture_default_str();
  app.add_option("--resolution", a->resolution,
                 "TSDF voxels along the crop box's longest side (0: from the rendered pixels' size)")
      ->capture_default_str();
  app.add_option("--method", a->method, "Mesh from depth maps fused in a TSDF (tsdf) or from the points (poisson)")
      ->capture_default_str();
  app.add_option("--crop", a->crop,
                 "xmin,ymin,zmin,xmax,ymax,zmax in the output frame (default: what the cameras look at)");
  app.add_option("--frame", a->frame, "capture (the input poses' coordinates) or scene (normalised)")
      ->capture_default_str();
  app.add_option("--views", a->views, "Cameras of the capture rendered at most")->capture_default_str();
  app.add_option("--max-side", a->max_side, "Rendered images' longest side at most (pixels)")->capture_default_str();
  app.add_option("--mask", a->mask, "alpha: the photos' transparent pixels give no geometry; none")
      ->capture_default_str();
  app.add_option("--depth", a->depth,
                 "The attention depth that becomes the surface: front (where its first 15% lie nearer), mean, or "
                 "auto (front; mean for forward-facing runs)")
      ->capture_default_str();
  app.add_option("--preview", a->preview,
                 "A picture of the points with the cameras that saw them, as FILE.png (default "
                 "RUN/geometry_preview.png, shown in the run's report; none: no picture)");
  app.add_option("--device", a->device, "cpu, cuda, cuda:N or auto (cuda when available)")->capture_default_str();
  add_json_flag(app);
  app.callback([a] { run_export(*a); });
}

}  // namespace cmd_export
ABLENERF_COMMAND("export", 60, "Export model weights, or the scene as points and a mesh", cmd_export::setup);
}  // namespace ablenerf::cli
