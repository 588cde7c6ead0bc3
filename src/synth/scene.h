#pragma once
// The embedded demo scene as a Blender-format dataset (`ablenerf synth`): a diffuse checkered
// sphere, a mirror sphere and a glass sphere under a procedural environment, rendered by a small
// CPU ray tracer (world.h, camera.h, render.h) on a transparent background.
//
// Layout written to DIR:
//   transforms_train.json, transforms_test.json  (camera_angle_x + frames, Blender style)
//   train/r_K.png, test/r_K.png                  (RGBA 8-bit, straight alpha, sRGB)
//   test/r_K_depth.pt                            (torch::pickle_save of float32 (H,W) depth)
//   test/r_K_depth.png                           (greyscale visualisation of that depth)
//   scene.json                                   (objects, materials, lighting, cameras, seed)
#include <cstdint>
#include <functional>
#include <string>

#include "synth/camera.h"
#include "synth/render.h"
#include "synth/world.h"

namespace ablenerf::synth {

constexpr int kMinResolution = 8;
constexpr int kMaxResolution = 4096;
constexpr int kMaxViews = 100000;

struct SynthOptions {
  int res = 100;
  int train_views = 100;
  int test_views = 20;
  uint64_t seed = 0;
  int threads = 0;  // <= 0: hardware concurrency, at least 2
  // Called after each finished view with (views done, views total); from worker threads,
  // serialised by a mutex. May be empty.
  std::function<void(int, int)> progress;
};

// Throws InputError("synth", "--res" / "--train-views" / "--test-views", ...) on bad options.
void validate(const SynthOptions& opts);

// Renders every view and writes the dataset (each file atomically). Deterministic for a seed:
// the same options give byte-identical files whatever the thread count.
void write_synthetic_dataset(const std::string& dir, const SynthOptions& opts);

}  // namespace ablenerf::synth

namespace ablenerf {
using synth::SynthOptions;
using synth::write_synthetic_dataset;
}  // namespace ablenerf
