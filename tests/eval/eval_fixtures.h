#pragma once
// Shared fixtures of the eval tests: a tiny Blender scene written on the fly, and a run folder
// holding a fresh (untrained) model of test::tiny_model_config() (test_util.h).
#include <torch/torch.h>

#include <string>

#include "run/run_folder.h"
#include "util/config.h"

namespace ablenerf::test {

// A Blender-format scene in `dir`: `n_train` train and `n_test` test views of w x h, cameras at
// distance 4 around the origin; RGBA images with an opaque left half (smooth colours) and a
// transparent right half. With `with_depth`, every test view gets a depth_file_path tensor:
// depth 4 on the top half of the image, 0 elsewhere.
void make_tiny_scene(const std::string& dir, int n_train, int n_test, int w, int h, bool with_depth);

// RunFolder::create + save_weights of a fresh tiny model (seeded) + a short log.jsonl.
RunFolder make_tiny_run(const std::string& run_dir, const std::string& data_dir);

// Gives the run's weights appearance codes (model/appearance_code.h): `codes` (photos, model width).
void give_run_appearance_codes(const std::string& run_dir, const torch::Tensor& codes);

}  // namespace ablenerf::test
