#pragma once
// The image size a capture trains at when the config leaves it to the capture (data.downscale = 0,
// the capture preset): the finest reduction (of kAutoDownscales) whose training pixels the run can draw
// data.auto_passes times in its budget, at data.auto_rays_per_s (the capture preset's: its speed on 2
// CPU cores, so that one command picks one size) or the training speed measured on this machine,
// and no coarser than keeps data.auto_min_side pixels on the images' short side. A fixed data.downscale
// (or `train --downscale N`) overrides it; the choice is recorded in the run's config, so that
// eval, render, view and export read the images at the size the model was trained on.
#include <torch/torch.h>

#include <functional>
#include <string>

#include "data/capture.h"
#include "util/config.h"

namespace ablenerf {

struct ImageSizeChoice {
  int downscale = 1;
  int64_t frames = 0;         // training photos
  int width = 0, height = 0;  // their size at the chosen reduction
  double pixels = 0;          // training pixels at the chosen reduction
  double rays = 0;            // rays the run will draw (steps x rays per step, or budget x speed)
  double rays_per_s = 0;      // the speed assumed (0 when the run is counted in steps)
  bool measured = false;      // ... measured on this machine, not data.auto_rays_per_s
  double passes() const { return pixels > 0 ? rays / pixels : 0; }
  // One line: the choice and why.
  std::string describe() const;
};

// Reductions tried, finest first: powers of two (the sizes JPEG decodes at directly and the
// images_N/ folders captures come with) and three times them (decoded at a power of two, then a
// 3x3 box), so that a step costs at most a factor 1.8 in pixels.
inline constexpr int kAutoDownscales[] = {1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64};

// The rays a run of `cfg` draws: train.steps x train.rays_per_step, or fewer when train.time_budget_s
// at `rays_per_s` ends it first (rays_per_s only matters with a budget).
double planned_rays(const Config& cfg, double rays_per_s);

// The choice for a capture (its "train" split's photos, its full size), pure arithmetic; `loadable`,
// when given, says which reductions the capture can be read at (one that ships only images_8/
// has no other), and the others are passed over.
ImageSizeChoice choose_image_size(const Capture& full, const Config& cfg, double rays_per_s,
                                  const std::function<bool(int)>& loadable = {});

// With data.downscale = 0: the capture at `data_dir` read at full size, the training speed (when
// the run has a time budget) data.auto_rays_per_s or else measured (a few steps of the config's
// own trainer on `device`, under a second on 2 CPU cores), the choice written into cfg's
// data.downscale and returned. Otherwise
// nothing changes and the result's downscale is cfg's.
ImageSizeChoice resolve_image_size(Config& cfg, const std::string& data_dir, const torch::Device& device);

}  // namespace ablenerf
