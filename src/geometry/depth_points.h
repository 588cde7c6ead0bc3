#pragma once
// Surface points from depth maps (docs/ARCHITECTURE.md, "Geometry out"): every pixel of a camera
// whose depth is known becomes the point origin + depth * direction of its ray (rays.h: directions
// have camera-frame z = -1, so depth is along the optical axis), with its colour. Lens models are
// undone by the rays themselves. Torch only; the fusion into meshes is fuse.h's (Open3D).
#include <torch/torch.h>

#include <array>

#include "data/camera.h"
#include "data/scene_frame.h"

namespace ablenerf {

// An axis-aligned box [lo, hi] of the scene frame.
struct CropBox {
  std::array<double, 3> lo{-1, -1, -1}, hi{1, 1, 1};
  bool contains(const std::array<double, 3>& p) const;
  // Which rows of xyz (N,3) lie inside the box: (N) bool.
  torch::Tensor inside(const torch::Tensor& xyz) const;
  double diagonal() const;
  // The box holding the `share` of the points (N,3) between each axis's (1 - share) / 2 and
  // (1 + share) / 2 quantiles, widened by `margin` of its size on every side: a crop for scenes
  // whose extent only the geometry itself tells (forward-facing captures). N > 0.
  static CropBox around(const torch::Tensor& xyz, double share, double margin);
  // "xmin,ymin,zmin,xmax,ymax,zmax"; InputError naming `option` on anything else (or an empty box).
  static CropBox parse(const std::string& text, const std::string& option);
};

// Points of one view: (N,3) positions, (N,3) colours in [0,1], (N,3) unit normals when known.
struct PointSet {
  torch::Tensor xyz, rgb, normals;
  int64_t size() const { return xyz.defined() ? xyz.size(0) : 0; }
};

// The points of every pixel of a (3,4) camera-to-world pose whose depth lies in (near, far) and
// whose point lies inside `crop`. depth: (H,W), rgb: (H,W,3), both for the camera `k`; `keep`
// (H,W) bool, when defined, drops the pixels it is false at. Float32 on the CPU.
PointSet points_from_depth(const torch::Tensor& c2w, const Intrinsics& k, const torch::Tensor& depth,
                           const torch::Tensor& rgb, double near, double far, const CropBox& crop,
                           const torch::Tensor& keep = {});

// Points (N,3) of the scene frame in the capture's own coordinates (SceneFrame::to_capture's
// inverse of point_to_scene).
torch::Tensor points_to_capture(const torch::Tensor& xyz, const SceneFrame& scene);

// Unit normals (N,3) of the scene frame turned into the capture's coordinates (the frame's rotation
// only: no scale or shift).
torch::Tensor normals_to_capture(const torch::Tensor& normals, const SceneFrame& scene);

// Concatenation of point sets (normals kept only when every set has them).
PointSet concat_points(const std::vector<PointSet>& sets);

}  // namespace ablenerf
