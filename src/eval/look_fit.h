#pragma once
// NeRF-W's evaluation protocol for per-photo appearance (Martin-Brualla et al. 2021, section 6.2;
// eval.fit_look, `eval --fit-look`): a held-out photo's exposure and white balance cannot be known
// from the training photos, so each test view's look is fitted on the left half of its photo and
// the scores are taken on the right half only. Here the look is the per-photo colour's form
// (model/photo_colour.h: an affine map of the rendered colour, 3x3 plus a bias), which enters after
// the render, so the fit with the model frozen is linear least squares on the render, solved in
// closed form instead of by gradient steps.
//
// A run with per-photo appearance codes (model/appearance_code.h) has, besides, the code NeRF-W
// itself fits: the view's code is fitted first by gradient steps on the left half's pixels (from
// zero, the photos' mean look), the render taken with it, and the colour map fitted on that render.
#include <torch/torch.h>

#include "eval/photo_fit.h"

namespace ablenerf {

struct LookFit {
  torch::Tensor map;     // (4,3) float64: [r g b 1] x map = the fitted colour
  torch::Tensor fitted;  // (H,W,3) float32: the render through the map, clamped to [0,1]
};

// The affine colour map that takes `render` (H,W,3) closest to `photo` (H,W,3) in squared error over
// the left half's columns (0 .. W/2-1; only where `keep` (H,W) is true when it is defined), and the
// whole render through it. A left half with fewer than 4 pixels, or whose colours do not span a
// plane, keeps the identity.
LookFit fit_look_left_half(const torch::Tensor& render, const torch::Tensor& photo, const torch::Tensor& keep = {});

struct CodeFit {
  torch::Tensor code;  // (1, width) on the model's device, no gradient: ForwardOptions::appearance
  PhotoFit fit;
};

// The appearance code that takes the model's render of camera c2w (3,4) closest to `image` (H,W,3)
// on the left half's columns (where `keep` (H,W) is true when it is defined), the model frozen;
// o.lr is on the code itself. The model must have appearance codes.
CodeFit fit_code_left_half(AbleNerf& model, const torch::Tensor& c2w, const Intrinsics& cam, const torch::Tensor& image,
                           const torch::Tensor& keep, double near, double far, const PhotoFitOptions& o,
                           const torch::Device& device);

}  // namespace ablenerf
