#pragma once
// A run folder, the unit that `train` writes and `eval`, `render`, `export` read:
//   RUN/config.toml     resolved config (every key)
//   RUN/run.json        {"data": dataset folder, "version": ablenerf version}
//   RUN/weights.pt      latest model weights (save_weights format, torch.load-able dict)
//   RUN/checkpoint.pt   full training state (model, Adam, step, RNG), checksummed; see train/checkpoint.h
//   RUN/scene.json      the capture's scene frame (data/scene_frame.h): capture -> scene transform,
//                       bounded/unbounded, near/far; absent for runs from before it (Blender identity)
//   RUN/log.jsonl       one JSON object per line: {"type":"train", step, loss, terms (the loss's terms by
//                       name, train/grad_accumulation.h), psnr, lr, rays_per_s, elapsed_s} or
//                       {"type":"eval", step, psnr, views, split}; see run/run_log.h
//   RUN/eval/SPLIT/     eval outputs (images, error and depth maps, metrics.json)
//   RUN/report.html     the self-contained report
//   RUN/exports.json    what `export --points / --mesh` wrote, one object per export (geometry/export_geometry.h)
#include <torch/torch.h>

#include <nlohmann/json.hpp>
#include <string>

#include "data/scene_frame.h"
#include "model/able_nerf.h"
#include "util/config.h"

namespace ablenerf {

struct RunFolder {
  std::string dir;
  Config config;
  std::string data_dir;

  // Reads RUN/config.toml and RUN/run.json; InputError naming the file when absent or bad.
  static RunFolder open(const std::string& dir);
  // Creates the folder and writes config.toml and run.json atomically.
  static RunFolder create(const std::string& dir, const Config& config, const std::string& data_dir);

  std::string path(const std::string& name) const { return dir + "/" + name; }
  std::string weights_path() const { return path("weights.pt"); }
  std::string checkpoint_path() const { return path("checkpoint.pt"); }
  std::string log_path() const { return path("log.jsonl"); }
  std::string report_path() const { return path("report.html"); }
  std::string scene_path() const { return path("scene.json"); }
  std::string exports_path() const { return path("exports.json"); }

  // RUN/exports.json's list (geometry/export_geometry.h writes it): an empty array when the run
  // has none; InputError naming the file when it is not JSON or not an array.
  nlohmann::json exports() const;

  // RUN/scene.json, written atomically by `train`.
  void write_scene(const SceneFrame& scene) const;
  // RUN/scene.json; without one (older runs) the identity frame with the config's scene and near/far.
  SceneFrame scene() const;

  // A kill -9 during an atomic write (util/fs.h) leaves its temporary file behind while the real
  // file is intact: removes the temporaries of this folder's own outputs (weights, checkpoint,
  // config, run.json, report). Other files are left alone.
  void remove_stale_temporaries() const;
};

// The run's model with its latest weights, in eval mode, on `device`.
AbleNerf load_run_model(const RunFolder& run, const torch::Device& device);

}  // namespace ablenerf
