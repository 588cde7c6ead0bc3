#pragma once
// Camera refinement (train.camera_refine; docs/MODEL.md, "Camera refinement"), ablenerf's extension
// for captures whose poses come from structure from motion and are a little off: each training
// photo p gets a rigid correction learned with the scene, a rotation exp([w_p]x) about the camera's
// centre and a shift t_p of the centre, both in the scene frame (nerfstudio's "SO3xR3" camera
// optimiser; BARF, Lin et al. 2021, learns the same six numbers per camera). A photo's rays become
//   origin' = origin + t_p,   direction' = exp([w_p]x) direction,
// which is the ray of the corrected camera-to-world [exp([w_p]x) R | c + t_p]: the samples move
// with the pose, so the loss reaches w and t through the sample positions (the grid's lookup passes
// the positions' gradient: kernels/hash_grid.h), the frustums and the view direction. Moving every
// camera alike and the scene with them fits the photos as well: the rig's rigid motions and its
// scaling about its centre (to first order, the corrections w_p = w, t_p = w x c_p + t + s (c_p - c))
// change no photo. So the corrections applied are the parameters with that part taken out
// (correction(): the rig's gauge removed; the scene stays where the poses put it, and held-out
// cameras still see it), and a small decay (train.camera_refine_decay) keeps corrections that the
// images do not ask for at zero.
//
// Optionally (train.camera_refine_focal) one focal-length scale k = exp(f) for the whole capture,
// whose photos share one camera model (`process` makes one camera): a camera of focal length k fx,
// k fy casts the pixel's ray of camera-frame direction (u / k, v / k, -1) where the given one cast
// (u, v, -1), so in the scene frame the component of a direction across the camera's optical axis
// a_p shrinks by k and the one along it stays,
//   direction_k = (d . a_p) a_p + (d - (d . a_p) a_p) / k,   radius_k = radius / k,
// applied before the turn. For a pinhole this is exactly the camera of focal length k fx; through a
// lens it scales the undistorted directions (the lens's coefficients act on the given focal length's
// coordinates), which differs from rescaling the intrinsics by (k - 1) times the distortion: small
// beside what k corrects. Held-out photos are rendered with the scaled intrinsics (refined()). The
// parameter is log k over lr_scale, as the corrections'. A capture seen from afar hardly fixes k: a
// scene scaled by k looks the same to within its depth range over the distance times (k - 1), and
// the scene's scale is free (docs/MODEL.md, "Camera refinement", 8.).
#include <torch/torch.h>

#include "data/camera.h"
#include "data/rays.h"

namespace ablenerf {

// The corrections learn at this fraction of the run's learning rate: each photo has only a few of a
// step's rays, so its gradient is noisy, and Adam's steps of about the learning rate would make the
// pose wander (docs/MODEL.md, "Camera refinement").
constexpr double kCameraRefineLrScale = 0.1;

// BARF's coarse-to-fine schedule (Lin et al. 2021, section 3.3; train.camera_refine_c2f_start /
// _end): while the poses settle, the positional encoding's high frequencies, whose gradients with
// respect to a pose point every which way, are held back and opened one band at a time. Band k of
// the IPE's `degrees` is scaled by w_k = (1 - cos(pi clamp(alpha - k, 0, 1))) / 2. BARF's alpha runs
// from 0 to the band count; the paper's IPE has no raw position beside its bands (BARF keeps one),
// so here the lowest band is open from the start: alpha = 1 + (degrees - 1) x the schedule's
// progress from `start` to `end` (shares of the run), clamped.
double coarse_to_fine_alpha(double fraction, double start, double end, int64_t degrees);
// The IPE features' weights (6 x degrees, the IPE's layout: all sines, then all cosines, band-major
// with three axes per band; model/ipe.h) at `alpha`.
torch::Tensor frequency_window_weights(double alpha, int64_t degrees);

class CameraRefineImpl : public torch::nn::Module {
 public:
  // lr_scale: the corrections' learning rate over the run's; the parameter Adam sees (and weights
  // files hold) is the corrections over lr_scale. centred: the rig's gauge is taken out of the
  // corrections (training: see above; set_centres gives its geometry); not for a lone camera fitted
  // on its own (eval/camera_align.h).
  // focal: also learn the capture's focal-length scale (above).
  explicit CameraRefineImpl(int64_t cameras, double lr_scale = kCameraRefineLrScale, bool centred = true,
                            bool focal = false);
  // The given cameras' centres (cameras, 3) in the scene frame, which the gauge's turn and scaling
  // move (the trainer and `export --cameras` set them from the poses). Until set, all at the origin:
  // the gauge is then the common shift and turn alone, and correction() the parameter minus its mean.
  void set_centres(const torch::Tensor& centres);
  // The given camera-to-world matrices (cameras, 3 or 4, 4): their centres (set_centres) and their
  // optical axes (the third column), which the focal scale needs.
  void set_cameras(const torch::Tensor& c2w);
  bool refines_focal() const { return focal_.defined(); }
  // k, the focal-length scale: a 0-dimensional tensor (1 without focal refinement), and as a number.
  torch::Tensor focal_scale() const;
  double focal_scale_value() const;
  // The intrinsics `k` of a photo of this capture with the refined focal length (k fx, k fy; the
  // principal point and the lens unchanged): the camera held-out photos and rendered views use.
  Intrinsics refined(const Intrinsics& k) const;
  // The rays of photos `photo` (B,) (int64, < cameras()) as their corrected cameras cast them
  // (with focal refinement, set_cameras must have given the axes).
  Rays forward(const Rays& rays, const torch::Tensor& photo);
  int64_t cameras() const { return param_.size(0); }
  // The corrections applied: (cameras, 6), w (axis times angle, radians) then t; zero = the poses as
  // given. Centred: with w_g the parameters' mean turn, t_g the mean of t_p - w_g x c_p, and s the
  // least-squares scaling of the rest about the centres' mean c, each camera's (w_p - w_g,
  // t_p - w_g x c_p - t_g - s (c_p - c)), times lr_scale: a projection (applied twice it changes
  // nothing) whose kernel is the gauge, so any correction of the rig modulo the gauge stays
  // reachable; subtracting the plain mean instead also removed the cameras' common turn about their
  // own centres, which no gauge motion gives (docs/MODEL.md, "Camera refinement", 3.).
  torch::Tensor correction() const;
  // The parameter itself (correction() / lr_scale()) and the scale.
  const torch::Tensor& parameter() const { return param_; }
  double lr_scale() const { return lr_scale_; }
  // (cameras, 3, 3): exp([w]x) of every camera (Rodrigues' formula in closed form, no host copy:
  // it runs inside a captured CUDA graph).
  torch::Tensor rotations() const;
  // The corrected camera-to-world matrices (cameras, 3, 4) of the given ones (cameras, 3 or 4, 4).
  torch::Tensor corrected(const torch::Tensor& c2w) const;

 private:
  double lr_scale_;
  bool centred_;
  torch::Tensor param_;
  torch::Tensor focal_;    // (1,): log k over lr_scale; undefined without focal refinement
  torch::Tensor centres_;  // (cameras, 3), not a parameter: set_centres
  torch::Tensor axes_;     // (cameras, 3), the optical axes, not a parameter: set_cameras
};
TORCH_MODULE(CameraRefine);

}  // namespace ablenerf
