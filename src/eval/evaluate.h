#pragma once
// `ablenerf eval` as a library call: renders the first N views of a split with a run's model,
// scores them (PSNR, SSIM, LPIPS, and depth error when the dataset has ground-truth depth) and
// writes RUN/eval/SPLIT/:
//   r_K.png        the render (sRGB, 8-bit)
//   r_K_gt.png     the dataset image as the model sees it (downscaled, composited)
//   r_K_error.png  mean-over-channels |render - gt|, colour-mapped on [0, kErrorMapMax]
//   r_K_depth.png  the attention front's depth (renderer.h), colour-mapped on [near, far] (no alpha)
//   metrics.json   per-image and mean scores (see evaluate_run)
#include <torch/torch.h>

#include <cstdint>
#include <functional>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>

#include "run/run_folder.h"

namespace ablenerf {

// Upper end of the error-map colour scale (absolute error per pixel, mean over RGB): errors of
// 0.25 and above are drawn in the brightest colour.
constexpr double kErrorMapMax = 0.25;
// Ground-truth pixels that count towards depth error: depth > 0 and alpha above this.
constexpr double kDepthAlphaThreshold = 0.5;

struct EvalOptions {
  std::string split = "test";
  int64_t max_images = -1;            // < 0: every view of the split
  std::optional<int> downscale;       // unset: the run's data.downscale
  std::string data_dir;               // "": the run's dataset (run.json)
  std::string ssim;                   // "standard" | "release" | "": the run's eval.ssim
  std::string lpips_weights;          // "": default_lpips_weights_path(); none found -> LPIPS skipped
  std::optional<int64_t> chunk;       // rays per forward; unset: the run's eval.chunk
  std::optional<bool> align_cameras;  // unset: the run's eval.align_cameras (eval/camera_align.h)
  std::optional<bool> fit_look;       // unset: the run's eval.fit_look (eval/look_fit.h)
  torch::Device device = torch::kCPU;
  bool progress = true;  // progress line with ETA on stderr
  // One-line notes for the user (LPIPS skipped, ...); default: stderr.
  std::function<void(const std::string&)> note;
};

// RUN/eval/SPLIT
std::string eval_dir(const RunFolder& run, const std::string& split);

// Runs the evaluation, writes the files above and returns metrics.json's content:
// {"split", "images": [{"index", "file", "render", "psnr", "ssim", "lpips", "seconds"
//   [, "depth_mae", "depth_mae_argmax"]}], "mean": {"psnr", "ssim", "lpips" [, "depth_mae",
//   "depth_mae_argmax"]}, "seconds_per_image", "lpips_weights", "ssim_variant", "step",
//   "width", "height", "near", "far", "error_map_max", "data", "protocol"}; with aligned cameras
// ("protocol": "aligned cameras", else "plain") each image also has "aligned_rotation_deg" and
// "aligned_shift", and "camera_alignment" says how they were fitted. With a fitted look (NeRF-W's
// protocol, "protocol" names it) the scores are the right half's, each image has "look_map" (the
// fitted 4x3 map) and "look_fit" says how; the render written is the one through the map.
// Scores that could not be computed (no LPIPS weights, image too small, infinite PSNR) are null.
// Throws InputError for a bad run folder, dataset, split or option.
nlohmann::json evaluate_run(const RunFolder& run, const EvalOptions& opts);

}  // namespace ablenerf
