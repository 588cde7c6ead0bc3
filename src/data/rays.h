#pragma once
// Cameras and rays (spec 1.2): pixel centres, unnormalised directions whose camera-frame z is
// exactly -1 (so t is depth along the optical axis), mip-NeRF base radius per ray.
#include <torch/torch.h>

namespace ablenerf {

// Colour channels of a pixel, a ray's target and every colour output.
constexpr int64_t kRgbChannels = 3;

// Pinhole intrinsics in pixels. Blender scenes: fx = fy = 0.5 W / tan(0.5 camera_angle_x),
// cx = W/2, cy = H/2.
struct Intrinsics {
  double fx = 1, fy = 1, cx = 0, cy = 0;
  int width = 0, height = 0;
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

// mip-NeRF base radius: the distance between the directions of vertically adjacent pixels
// (exactly 1/fy for a pinhole camera) times 2/sqrt(12).
double pixel_radius(const Intrinsics& k);

// Rays through pixel centres (col + 0.5, row + 0.5). c2w: (B,3,4) or (B,4,4) camera-to-world
// (OpenGL axes); col,row: (B) integer or float pixel indices. All on the same device.
Rays rays_for_pixels(const torch::Tensor& c2w, const torch::Tensor& col, const torch::Tensor& row,
                     const Intrinsics& k);

// Every ray of one image, row-major (H*W rays). c2w: (3,4) or (4,4).
Rays rays_for_image(const torch::Tensor& c2w, const Intrinsics& k);

}  // namespace ablenerf
