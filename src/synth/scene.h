#pragma once
// The embedded synth scenes as datasets (`ablenerf synth`), rendered by a small CPU ray tracer
// (render.h) with exact test-view depth:
//  - "demo" (the default): a diffuse checkered sphere, a mirror sphere and a glass sphere under a
//    procedural environment (world.h), seen from outside by cameras looking at them (camera.h), on
//    a transparent background: a Blender object scene;
//  - "room": a furnished box room photographed from inside by cameras looking outward (room.h,
//    room_camera.h): opaque everywhere, written as a real capture (the nerfstudio layout).
//
// Variants for real-capture code paths: `lens` "opencv" renders through kWideLens (camera.h),
// `background` "environment" puts the sky and ground (at infinity) behind the objects instead of a
// transparent card (demo only). Either writes the nerfstudio layout (below) unless `layout` says
// otherwise.
//
// Layout written to DIR ("blender", the demo's default):
//   transforms_train.json, transforms_test.json  (camera_angle_x + frames, Blender style)
//   train/r_K.png, test/r_K.png                  (RGBA 8-bit, straight alpha, sRGB)
//   test/r_K_depth.pt                            (torch::pickle_save of float32 (H,W) depth)
//   test/r_K_depth.png                           (greyscale visualisation of that depth)
//   scene.json                                   (the scene's name, objects, materials, lighting,
//                                                 cameras, seed; with jitter or pose noise, each
//                                                 train view's gains and true pose under
//                                                 "train_view_truth"; with a distractor, each
//                                                 train view's ball)
//   train/r_K_mask.png                           (with a distractor: white keeps, black is the ball)
// ("nerfstudio", the room's and the variants' default): one transforms.json with w, h, fl_x, fl_y,
// cx, cy, camera_model (PINHOLE or OPENCV with k1 k2 p1 p2), every frame, and the split as
// train_filenames / test_filenames; the same image, depth and scene.json files.
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
  std::string scene = "demo";  // "demo" | "room"
  int res = 100;
  int train_views = 100;
  int test_views = 20;
  uint64_t seed = 0;
  int threads = 0;                         // <= 0: hardware concurrency, at least 2
  std::string lens = "pinhole";            // "pinhole" | "opencv"
  std::string background = "transparent";  // "transparent" | "environment"
  std::string layout = "auto";             // "auto" | "blender" | "nerfstudio"
  // What a phone capture does to its photos, on the train views only, with the truth in scene.json
  // (seeded by `seed`; the test views stay clean, the look novel views should have):
  //  - exposure_jitter: each train view's exposure changes by e stops, e uniform in [-s, s] and then
  //    centred (the views' mean is 0), so the clean look is the views' average look;
  //  - white_balance_jitter: the red and blue gains likewise, in stops, each centred;
  //    the gains multiply the linear radiance before the film clamps it;
  //  - pose_noise_deg / pose_noise_shift: the pose written for each train view is its true pose
  //    turned by exactly pose_noise_deg about a random axis through the camera centre and moved by
  //    pose_noise_shift x the camera's distance in a random direction (the image is rendered from the
  //    true pose). The distance is the demo camera's from the origin it looks at, and the room
  //    camera's from what it looks at (the first surface along its optical axis).
  double exposure_jitter = 0;
  double white_balance_jitter = 0;
  double pose_noise_deg = 0;
  double pose_noise_shift = 0;
  //  - distractor: each train view also sees a flat magenta ball (radius kDistractorRadius) at a
  //    place of its own between the camera and the objects, and gets a mask beside its photo
  //    (train/r_K_mask.png, white = keep, black = the ball) named by its frame's mask_path. Demo only.
  bool distractor = false;
  // The layout "auto" resolves to: nerfstudio for the room and for the lens or background
  // variants, else blender.
  std::string resolved_layout() const;
  // Called after each finished view with (views done, views total); from worker threads,
  // serialised by a mutex. May be empty.
  std::function<void(int, int)> progress;
};

// Throws InputError("synth", "--scene" / "--res" / "--train-views" / "--test-views" / "--lens" /
// "--background" / "--layout" / "--exposure-jitter" / "--white-balance-jitter" / "--pose-noise-deg" /
// "--pose-noise-shift" / "--distractor", ...) on bad options; the room refuses --background
// environment (it is closed: nothing lies behind its walls), --distractor and --layout blender (it
// is a real capture, not a Blender object scene).
constexpr double kMaxJitterStops = 4.0;
constexpr double kMaxPoseNoiseDeg = 45.0;
constexpr double kMaxPoseNoiseShift = 0.5;
constexpr double kDistractorRadius = 0.25;
void validate(const SynthOptions& opts);

// Renders every view and writes the dataset (each file atomically). Deterministic for a seed:
// the same options give byte-identical files whatever the thread count.
void write_synthetic_dataset(const std::string& dir, const SynthOptions& opts);

}  // namespace ablenerf::synth

namespace ablenerf {
using synth::SynthOptions;
using synth::write_synthetic_dataset;
}  // namespace ablenerf
