#pragma once
// Cameras and rays (docs/MODEL.md, section 1): pixel centres, unnormalised directions whose camera-frame z is
// exactly -1 (so t is depth along the optical axis), mip-NeRF base radius per ray. A distorted
// lens (camera.h, lens.h) is undone per pixel: the pixel centre is undistorted before it becomes a
// direction, and the radius follows the undistorted pixel's height.
#include <torch/torch.h>

#include <vector>

#include "data/camera.h"

namespace ablenerf {

// Colour channels of a pixel, a ray's target and every colour output.
constexpr int64_t kRgbChannels = 3;

// Cameras as tensors for batched ray generation, one row per image (or per ray after index()).
struct CameraTable {
  torch::Tensor params;  // (N, 4 + kLensCoeffs) float64: fx fy cx cy k1 k2 k3 k4 p1 p2
  torch::Tensor model;   // (N) int64 LensModel
  // The distinct models in the table, known on the host: ray generation picks its code path from
  // this instead of reading `model` back from the device (no sync, so it can be graph-captured).
  std::vector<LensModel> models;

  static CameraTable of(const std::vector<Intrinsics>& cams, const torch::Device& device = torch::kCPU);
  int64_t size() const { return model.defined() ? model.size(0) : 0; }
  // Rows `rows` (the models list is kept: a superset of the rows' models is harmless).
  CameraTable index(const torch::Tensor& rows) const;
  // The first row repeated n times (one camera for a whole image's rays).
  CameraTable repeat_first(int64_t n) const;
  bool all_pinhole() const { return models.size() == 1 && models[0] == LensModel::Pinhole; }
  CameraTable to(const torch::Device& device) const;
};

// A batch of rays. origins, directions: (B,3); radii: (B,1) (cone radius at t = 1).
struct Rays {
  torch::Tensor origins, directions, radii;
  int64_t size() const { return origins.size(0); }
  Rays to(const torch::Device& d) const { return {origins.to(d), directions.to(d), radii.to(d)}; }
  Rays slice(int64_t begin, int64_t end) const {
    return {origins.slice(0, begin, end), directions.slice(0, begin, end), radii.slice(0, begin, end)};
  }
};

// mip-NeRF base radius of a pinhole: the distance between the directions of vertically adjacent
// pixels (exactly 1/fy) times 2/sqrt(12). With a distorted lens the distance is that of the
// undistorted pixel's top and bottom edges (to first order), per pixel.
double pixel_radius(const Intrinsics& k);

// A ray in its camera's frame, before the pose: the pixel centre's normalised coordinates with the
// lens undone (OpenCV axes), rounded to float32 as the ray's direction is, and the cone radius at
// t = 1 (float32).
struct LensCoordinates {
  torch::Tensor x, y;   // (B) float32
  torch::Tensor radii;  // (B,1) float32
};

// The lens's part of rays_for_pixels: through pixel centres (col + 0.5, row + 0.5) of `cams` (one
// row per ray), in float64, on col's device. It depends on the camera and the pixel only, so a
// sampler may compute it once per camera and pixel and look it up (train/ray_batch.h).
LensCoordinates lens_coordinates(const torch::Tensor& col, const torch::Tensor& row, const CameraTable& cams);
// The pose's part: rays from camera-frame coordinates and c2w (B,3,4) or (B,4,4) (OpenGL axes).
Rays rays_from_lens_coordinates(const torch::Tensor& c2w, const LensCoordinates& lens);

// Rays through pixel centres (col + 0.5, row + 0.5). c2w: (B,3,4) or (B,4,4) camera-to-world
// (OpenGL axes); col,row: (B) integer or float pixel indices; cams: one camera row per ray
// (CameraTable::index). All on the same device.
Rays rays_for_pixels(const torch::Tensor& c2w, const torch::Tensor& col, const torch::Tensor& row,
                     const CameraTable& cams);
// Every ray through the same camera.
Rays rays_for_pixels(const torch::Tensor& c2w, const torch::Tensor& col, const torch::Tensor& row, const Intrinsics& k);

// Every ray of one image, row-major (H*W rays). c2w: (3,4) or (4,4).
Rays rays_for_image(const torch::Tensor& c2w, const Intrinsics& k);

}  // namespace ablenerf
