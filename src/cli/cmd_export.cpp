// `ablenerf export`: writes every model parameter as a torch.load-able name -> tensor
// dictionary (save_weights format, names in docs/weights.md), either from a run folder
// (RUN/config.toml + RUN/weights.pt) or freshly initialised from a config; and, from a run, the
// scene as geometry: coloured points (--points) and a mesh (--mesh), geometry/export_geometry.h.
#include <torch/torch.h>

#include <iostream>
#include <nlohmann/json.hpp>

#include "cli/command.h"
#include "cli/common.h"
#include "model/able_nerf.h"
#include "util/errors.h"
#ifdef ABLENERF_HAVE_GEOMETRY
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
  std::string points, mesh, method = "tsdf", crop, frame = "capture", device = "auto";
  int64_t num_points = 1'000'000, views = 48;
  int resolution = 0, max_side = 200;
  std::string mask = "alpha";
};

void run_export_weights(const ExportArgs& a) {
  if (a.run.empty() == a.cfg.config_path.empty())
    throw InputError("export", "--run", "give exactly one of --run RUN or --config FILE");
  if (!a.run.empty() && !a.cfg.sets.empty())
    throw InputError("export", "--set", "--set applies to --config only (a run's config is fixed)");
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
  o.device = parse_device(a.device);
  const RunFolder run = RunFolder::open(a.run);
  o.chunk = run.config.get<EvalConfig>().chunk;
  std::cout << export_geometry(run, o).dump() << std::endl;
#else
  throw EnvironmentError("export", "this build has no geometry export",
                         "install Open3D: apt-get install libopen3d-dev, then rebuild with scripts/setup.sh");
#endif
}

void run_export(const ExportArgs& a) {
  if (!a.points.empty() || !a.mesh.empty()) {
    if (!a.out.empty()) run_export_weights(a);
    run_geometry(a);
    return;
  }
  if (a.out.empty())
    throw InputError("export", "--out", "give --out FILE.pt (weights), --points FILE.ply or --mesh FILE");
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
  app.add_option("--device", a->device, "cpu, cuda, cuda:N or auto (cuda when available)")->capture_default_str();
  app.callback([a] { run_export(*a); });
}

}  // namespace cmd_export
ABLENERF_COMMAND("export", 60, "Export model weights, or the scene as points and a mesh", cmd_export::setup);
}  // namespace ablenerf::cli
