#pragma once
// What `ablenerf view` shows: a run's model, scene frame and dataset cameras, rendered on request
// at any size from any pose. One render at a time (a mutex): the model is not re-entrant, and on 2
// cores one image at a time is the fastest way through a queue anyway.
#include <torch/torch.h>

#include <array>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>

#include "data/dataset.h"
#include "model/able_nerf.h"
#include "run/run_folder.h"

namespace ablenerf {

// Image sides the viewer renders, in pixels.
constexpr int kViewMinSide = 8;
constexpr int kViewMaxSide = 2048;

enum class ViewMode { Rgb, Depth };

class ViewSession {
 public:
  // Loads RUN's weights and scene; the dataset's cameras are read without decoding images.
  ViewSession(const std::string& run_dir, const torch::Device& device);

  // {"scene", "near", "far", "width", "height", "fx", "fy", "cameras": [[12 numbers, row-major
  // camera-to-world 3x4 in the scene frame], ...], "step"}.
  nlohmann::json cameras_json() const;

  // The PNG of the view from `c2w` (row-major 3x4, scene frame, OpenGL axes) through a pinhole
  // with the dataset's focal length scaled to `width` (principal point at the centre).
  std::string render_png(const std::array<float, 12>& c2w, int width, int height, ViewMode mode);

 private:
  RunFolder run_;
  SceneFrame scene_;
  CameraList cams_;
  torch::Device device_;
  AbleNerf model_{nullptr};
  std::mutex mu_;
};

}  // namespace ablenerf
