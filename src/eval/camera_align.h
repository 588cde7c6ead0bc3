#pragma once
// Held-out cameras aligned against the frozen model before scoring (eval.align_cameras; docs/
// MODEL.md, "Camera refinement"): a run that refines its training cameras learns the scene in
// their corrected frame, which the held-out cameras, never refined, miss by whatever the
// refinement moved. Scoring a render through such a camera measures the pose, not the scene, so
// BARF (Lin et al. 2021) and nerfstudio's camera optimiser evaluation first fit each held-out
// camera's rigid correction (model/camera_refine.h) to its own photo with the model frozen, then
// render through the corrected camera. The protocol is named in metrics.json.
#include <torch/torch.h>

#include <cstdint>

#include "data/camera.h"
#include "model/able_nerf.h"

namespace ablenerf {

struct CameraAlignOptions {
  int64_t steps = 100;  // Adam steps on the correction
  int64_t rays = 512;   // pixels per step, drawn uniformly from the photo's kept pixels
  double lr = 1e-3;     // on the correction itself (radians, scene units)
  uint64_t seed = 0;    // the pixel draws
};

struct CameraAlignment {
  torch::Tensor c2w;                     // (3,4) the corrected camera-to-world
  double rotation_deg = 0;               // the correction's angle
  double shift = 0;                      // and its shift, in scene units
  double mse_before = 0, mse_after = 0;  // the fine colour's MSE on the first and the last step's pixels
};

// Fits a rigid correction of camera c2w (3,4) (intrinsics `cam`) to `image` (H,W,3) (pixels where
// `keep` (H,W) is true when it is defined) against `model`, whose parameters are left untouched.
CameraAlignment align_camera(AbleNerf& model, const torch::Tensor& c2w, const Intrinsics& cam,
                             const torch::Tensor& image, const torch::Tensor& keep, double near, double far,
                             const CameraAlignOptions& o, const torch::Device& device);

}  // namespace ablenerf
