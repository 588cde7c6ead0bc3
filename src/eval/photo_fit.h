#pragma once
// A few parameters of one held-out view fitted to its photo with the model frozen: the loop that
// eval's protocols share (a camera's rigid correction, eval/camera_align.h; an appearance code,
// eval/look_fit.h). Each step draws pixels uniformly from the allowed ones, renders them through
// the caller's forward (which reads the fitted parameters) and takes one Adam step on the fine
// colour's mean squared error, with the gradient taken for the fitted parameters only: the model's
// own parameters are neither given a .grad nor changed.
#include <torch/torch.h>

#include <cstdint>
#include <functional>
#include <vector>

#include "data/camera.h"
#include "data/rays.h"
#include "model/able_nerf.h"

namespace ablenerf {

struct PhotoFitOptions {
  int64_t steps = 100;  // Adam steps
  int64_t rays = 512;   // pixels per step
  double lr = 1e-3;     // on the fitted parameters themselves
  uint64_t seed = 0;    // the pixel draws
};

struct PhotoFit {
  double mse_before = 0, mse_after = 0;  // the fine colour's MSE on the first and the last step's pixels
};

// The model's output for the step's rays (cast through the view's one camera: camera index 0),
// computed from the parameters being fitted.
using PhotoFitForward = std::function<ModelOutput(const Rays& rays, const torch::Tensor& camera_index)>;

// Fits `params` (on `device`, requiring grad) so that forward's fine colour matches `image` (H,W,3)
// at the pixels `allowed` (row-major indices into H x W, int64) of camera c2w (3,4) with intrinsics
// `cam`. The model is in eval mode during the fit and left in the mode it had. No pixel allowed, or
// no step: nothing changes.
PhotoFit fit_to_photo(AbleNerf& model, const torch::Tensor& c2w, const Intrinsics& cam, const torch::Tensor& image,
                      const torch::Tensor& allowed, const std::vector<torch::Tensor>& params, const PhotoFitOptions& o,
                      const torch::Device& device, const PhotoFitForward& forward);

// The pixels (row-major indices, int64) where `keep` (H,W) is true, or all H x W when it is undefined,
// restricted to columns [col_begin, col_end).
torch::Tensor allowed_pixels(int64_t h, int64_t w, const torch::Tensor& keep, int64_t col_begin, int64_t col_end);

}  // namespace ablenerf
