// `ablenerf info`: validates and summarises a dataset (loading it exactly as training does)
// and/or a config (resolved keys and parameter count).
#include <iostream>
#include <nlohmann/json.hpp>

#include "cli/command.h"
#include "cli/common.h"
#include "data/load_options.h"
#include "data/data_config.h"
#include "data/dataset.h"
#include "eval/camera_path.h"
#include "train/image_size.h"

namespace ablenerf::cli {
namespace cmd_info {

nlohmann::json dataset_summary(const Dataset& ds) {
  nlohmann::json j;
  j["root"] = ds.root;
  j["format"] = ds.format;
  j["width"] = ds.intrinsics.width;
  j["height"] = ds.intrinsics.height;
  j["focal"] = {ds.intrinsics.fx, ds.intrinsics.fy};
  j["principal_point"] = {ds.intrinsics.cx, ds.intrinsics.cy};
  j["near"] = ds.near;
  j["far"] = ds.far;
  j["camera"] = ds.intrinsics.describe();
  j["scene"] = name_of(ds.scene.kind);
  j["scene_frame"] = ds.scene.describe();
  j["faces_one_way"] = ds.scene.faces_one_way;  // the cameras' layout (data/scene_frame.h)
  j["bounds_source"] = ds.scene.bounds_source;
  j["notes"] = ds.notes;
  j["load_seconds"] = ds.load_seconds;
  nlohmann::json splits = nlohmann::json::object();
  for (const auto& [name, s] : ds.splits) {
    nlohmann::json sj;
    sj["count"] = s.size();
    auto centres = s.c2w.select(2, 3);  // (N,3)
    auto mn = std::get<0>(centres.min(0)), mx = std::get<0>(centres.max(0));
    sj["camera_centre_min"] = {mn[0].item<double>(), mn[1].item<double>(), mn[2].item<double>()};
    sj["camera_centre_max"] = {mx[0].item<double>(), mx[1].item<double>(), mx[2].item<double>()};
    auto radius = centres.norm(2, 1);
    sj["camera_distance_min"] = radius.min().item<double>();
    sj["camera_distance_max"] = radius.max().item<double>();
    sj["mean_alpha"] = s.alpha.mean().item<double>();
    sj["has_depth"] = s.depth.defined();
    // The share of pixels that train (data.masks); 1 without masks.
    sj["unmasked_share"] = s.mask.defined() ? s.mask.to(torch::kFloat).mean().item<double>() : 1.0;
    splits[name] = sj;
  }
  j["splits"] = splits;
  // Where the cameras sit, seen from the scene's centre with +z up (what `render --path` sweeps):
  // the azimuth arc they cover (360 when they go all the way round) and their elevations.
  std::vector<torch::Tensor> poses;
  for (const auto& [name, s] : ds.splits) poses.push_back(s.c2w);
  const CameraRig rig = camera_rig(torch::cat(poses));
  const double deg = 180.0 / M_PI;
  j["coverage"] = {{"azimuth_deg", rig.full_circle() ? 360.0 : rig.azimuth_span * deg},
                   {"elevation_min_deg", rig.elevation_min * deg},
                   {"elevation_max_deg", rig.elevation_max * deg},
                   {"mean_distance", rig.distance}};
  return j;
}

void setup(CLI::App& app) {
  auto data = std::make_shared<std::string>();
  auto cfg = std::make_shared<ConfigOptions>();
  app.add_option("--data", *data, "Dataset folder to validate and summarise");
  cfg->add_to(app, false);
  add_json_flag(app);
  app.callback([data, cfg] {
    nlohmann::json out;
    if (!cfg->config_path.empty() || !cfg->preset.empty() || !cfg->sets.empty()) {
      const Config c = resolve_config(*cfg);
      out["config"] = config_summary(c);
    }
    if (!data->empty()) {
      Config c = resolve_config(*cfg);
      // data.downscale = 0: the size training would choose (train/image_size.h), said and used here.
      if (c.get<DataConfig>().downscale == 0)
        out["image_size"] = resolve_image_size(c, *data, parse_device("auto")).describe();
      LoadOptions lo = load_options_for(c);
      lo.progress = true;
      out["dataset"] = dataset_summary(Dataset::load(*data, lo));
    }
    if (out.is_null()) throw InputError("info", "--data", "give --data DIR and/or --config FILE or --preset NAME");
    std::cout << out.dump(2) << std::endl;
  });
}

}  // namespace cmd_info
ABLENERF_COMMAND("info", 70, "Validate and summarise a dataset (--data) and/or a config (--config)", cmd_info::setup);
}  // namespace ablenerf::cli
