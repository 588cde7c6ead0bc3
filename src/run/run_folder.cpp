#include "run/run_folder.h"

#include <filesystem>
#include <nlohmann/json.hpp>
#include <vector>

#include "model/compute.h"
#include "util/errors.h"
#include "util/fs.h"
#include "util/json_file.h"
#include "data/data_config.h"
#include "model/compute_config.h"
#include "model/model_config.h"

namespace fs = std::filesystem;

namespace ablenerf {

RunFolder RunFolder::open(const std::string& dir) {
  if (!fs::is_directory(dir)) throw InputError(dir, "", "run folder not found");
  RunFolder r;
  r.dir = dir;
  const std::string cfg = r.path("config.toml");
  if (!fs::exists(cfg)) throw InputError(cfg, "", "missing (not a run folder written by `ablenerf train`)");
  r.config = Config::load(cfg);
  const std::string info = r.path("run.json");
  if (fs::exists(info)) {
    const nlohmann::json j = read_json_file(info);
    if (!j.is_object() || !j.contains("data") || !j["data"].is_string())
      throw InputError(info, "data", "missing or not a string");
    r.data_dir = j["data"].get<std::string>();
  }
  return r;
}

RunFolder RunFolder::create(const std::string& dir, const Config& config, const std::string& data_dir) {
  ensure_dir(dir);
  RunFolder r;
  r.dir = dir;
  r.config = config;
  r.data_dir = data_dir.empty() ? std::string() : fs::absolute(data_dir).lexically_normal().string();
  write_file_atomic(r.path("config.toml"), config.to_toml());
  nlohmann::json j;
  j["data"] = r.data_dir;
  j["version"] = ABLENERF_VERSION;
  write_file_atomic(r.path("run.json"), j.dump(2) + "\n");
  return r;
}

void RunFolder::remove_stale_temporaries() const {
  std::vector<std::string> prefixes;
  for (const std::string& out :
       {weights_path(), checkpoint_path(), path("config.toml"), path("run.json"), report_path(), scene_path()})
    prefixes.push_back(fs::path(atomic_temp_prefix(out)).filename().string());
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir, ec)) {
    const std::string name = e.path().filename().string();
    for (const std::string& prefix : prefixes)
      if (name.rfind(prefix, 0) == 0) fs::remove(e.path(), ec);
  }
}

void RunFolder::write_scene(const SceneFrame& scene) const { write_file_atomic(scene_path(), scene.to_json()); }

nlohmann::json RunFolder::exports() const {
  if (!fs::exists(exports_path())) return nlohmann::json::array();
  const nlohmann::json all = read_json_file(exports_path(), " (move it away to start a new list)");
  if (!all.is_array()) throw InputError(exports_path(), "", "expected a JSON array of exports");
  return all;
}

SceneFrame RunFolder::scene() const {
  if (fs::exists(scene_path())) return SceneFrame::from_json(read_file(scene_path()), scene_path());
  SceneFrame f;
  f.kind = config.get<DataConfig>().scene == SceneKind::Unbounded ? SceneKind::Unbounded : SceneKind::Bounded;
  f.near = config.get<DataConfig>().near;
  f.far = f.kind == SceneKind::Unbounded ? kUnboundedFar : config.get<DataConfig>().far;
  return f;
}

AbleNerf load_run_model(const RunFolder& run, const torch::Device& device) {
  const SceneFrame scene = run.scene();
  AbleNerf model(run.config.get<ModelConfig>(), scene.kind, NdcProjection{scene.ndc_a, scene.ndc_b});
  if (!fs::exists(run.weights_path())) throw InputError(run.weights_path(), "", "missing (the run has no weights yet)");
  load_weights(model, run.weights_path());
  model->to(device);
  // A run trained in bf16 on a GPU still renders on a CPU: there, in fp32.
  model->set_compute(
      Compute::from_config(run.config.get<ComputeConfig>(), device, run.path("config.toml"), /*bf16_falls_back=*/true));
  model->eval();
  return model;
}

}  // namespace ablenerf
