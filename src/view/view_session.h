#pragma once
// What `ablenerf view` shows: a run's model, scene frame and dataset cameras, rendered on request
// at any size from any pose. One render at a time (a mutex): the model is not re-entrant, and on 2
// cores one image at a time is the fastest way through a queue anyway.
#include <torch/torch.h>

#include <array>
#include <chrono>
#include <atomic>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>

#include "data/dataset.h"
#include "data/capture.h"
#include "model/able_nerf.h"
#include "run/run_folder.h"

namespace ablenerf {

// Image sides the viewer renders, in pixels.
constexpr int kViewMinSide = 8;
constexpr int kViewMaxSide = 2048;
// Exported points the page draws over the view at most (a few milliseconds a frame in a browser).
constexpr int64_t kViewMaxPoints = 20000;

// Rgb: the render; Depth: attention depth, colour-mapped as eval's maps; Error: the render from
// the dataset camera nearest the asked pose (its pose and camera, at the asked size) against that
// camera's image, |render - image| averaged over RGB and colour-mapped on [0, kErrorMapMax].
enum class ViewMode { Rgb, Depth, Error };

// A run being trained (`train --view`): the viewer's buttons, and the training thread's side of
// them (called between steps through TrainOptions::between_steps).
class LiveControl {
 public:
  void pause();
  void resume();
  void request_save();
  bool paused() const;
  // The training thread: takes a pending save request (true once per request).
  bool take_save();
  // The training thread: while paused, waits up to `at_most` for a resume; returns whether still
  // paused.
  bool wait_if_paused(std::chrono::milliseconds at_most);

 private:
  mutable std::mutex mu_;
  std::condition_variable cv_;
  bool paused_ = false, save_ = false;
};

class ViewSession;
class Trainer;

// The live viewer's work between two training steps (TrainOptions::between_steps of
// `train --view`): copy the weights when a render asked for them, write a checkpoint when asked,
// and hold the training thread while paused (still saving on request; Ctrl-C ends the wait).
void view_between_steps(Trainer& trainer, ViewSession& session, LiveControl& control);

class ViewSession {
 public:
  // Loads RUN's weights and scene; the dataset's cameras are read without decoding images. `live`:
  // the run is being trained in this process; its weights arrive through set_weights, and the
  // model starts as the configured architecture (no weights file needed).
  ViewSession(const std::string& run_dir, const torch::Device& device, bool live = false);

  bool live() const { return live_; }
  // Live runs: whether a render has asked for weights newer than the ones held (an idle viewer
  // asks for nothing, so training pays nothing for it), and the copy itself (training thread,
  // between steps).
  bool wants_weights() const { return wants_.load(); }
  void set_weights(AbleNerf& trained, int64_t step);
  int64_t weights_step() const { return step_.load(); }
  int64_t weight_copies() const { return copies_.load(); }
  const RunFolder& run() const { return run_; }

  // {"scene", "near", "far", "width", "height", "fx", "fy", "cameras": [[12 numbers, row-major
  // camera-to-world 3x4 in the scene frame], ...], "step", "looks": [the training photos' file
  // names, whose looks render_png offers, when the run learnt per-photo colour or appearance codes;
  // else empty]}.
  nlohmann::json cameras_json() const;

  // The points of the run's latest points export (RUN/exports.json: `export --points`) in the scene
  // frame, evenly thinned to at most `max_points`, for the page to draw over the view:
  // {"file", "count" (points in the file), "points": [x, y, z, x, y, z, ...]}; with no such export,
  // or when its file cannot be read, "count" 0 and an empty list (and a "note" saying why).
  nlohmann::json points_json(int64_t max_points) const;

  // The PNG of the view from `c2w` (row-major 3x4, scene frame, OpenGL axes) through a pinhole
  // with the dataset's focal length scaled to `width` (principal point at the centre).
  // With ViewMode::Error, `camera` (when not null) receives the index of the camera compared.
  // `look` (ViewMode::Rgb): a training photo's look for the render (model/look.h: its appearance
  // code and its per-photo colour map, whichever the run learnt; the index of cameras_json()'s
  // "looks"), or -1 for the photos' mean look (the model's own colour); InputError naming "look" for
  // a run with neither or an index out of range.
  std::string render_png(const std::array<float, 12>& c2w, int width, int height, ViewMode mode, int* camera = nullptr,
                         int look = -1);
  // The dataset camera nearest `c2w` (centre distance plus the angle between viewing directions,
  // in scene units / radians), as an index of cameras_json()'s list.
  int nearest_camera(const std::array<float, 12>& c2w) const;

 private:
  RunFolder run_;
  SceneFrame scene_;
  CameraList cams_;
  std::vector<CaptureFrame> frames_;   // every split's frames, in cameras_json()'s order
  std::vector<std::string> looks_;     // the training photos' names (per-photo colour's order); empty without it
  int capture_h_ = 0, capture_w_ = 0;  // the capture's full image size
  torch::Device device_;
  AbleNerf model_{nullptr};
  std::mutex mu_;
  bool live_ = false;
  std::atomic<bool> wants_{false};
  std::atomic<int64_t> step_{-1}, copies_{0};
};

}  // namespace ablenerf
