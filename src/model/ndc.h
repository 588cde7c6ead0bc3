#pragma once
// Stage 1b (forward-facing scenes only; data.scene = "forward"): rays in normalised device
// coordinates, as NeRF and mip-NeRF do for LLFF's forward-facing captures. The scene frame puts the
// cameras near z = 0 looking down -z with every visible surface beyond z = -1 (data/scene_frame.h);
// a ray is moved to the plane z = -1 and mapped through the projection
//
//   NDC(x, y, z) = (-a x / z, -b y / z, 1 + 2 / z),   a = 2 fx / W, b = 2 fy / H,
//
// which sends the frustum beyond z = -1 to the cube [-1, 1]^3 (z = -1 -> -1, infinity -> 1). The
// ray stays a straight line, o' + t' d' with t' in [0, 1) from the near plane to infinity, and t'
// is linear in disparity. Samples are placed linearly in t' (bounded sampling between 0 and 1),
// the conical frustums are cast around the NDC ray, and their radius is the mean NDC offset
// between the origins of the horizontally and vertically neighbouring pixels' rays (multinerf's
// rule: in NDC a camera's rays are nearly parallel), here a finite difference of the map.
// The transformer, masks, LE and recipe are untouched; the view direction stays the world one.
#include <torch/torch.h>

#include "data/rays.h"

namespace ablenerf {

// The projection's focal factors a = 2 fx / W, b = 2 fy / H (scene.json's ndc_a / ndc_b).
struct NdcProjection {
  double a = 1, b = 1;
};

// Rays in the scene frame -> NDC rays (origins on the z' = -1 face, t' in [0, 1) to infinity).
// Rays must point down -z (d_z < 0) from in front of the plane z = -1 (o_z > -1); the scene frame
// of a forward-facing capture guarantees it for the capture's own cameras.
Rays rays_to_ndc(const Rays& rays, const NdcProjection& p);

// The point map alone, for tests: (..., 3) points with z < 0 -> NDC.
torch::Tensor points_to_ndc(const torch::Tensor& x, const NdcProjection& p);

// The metric depth (the scene-frame ray's own t, so depth along the optical axis: data/rays.h) of
// the point at NDC parameter t_ndc on each ray's NDC image (rays_to_ndc). The NDC ray meets the
// scene-frame point whose z is -near / (1 - t_ndc) (near: the NDC near plane, 1), whatever the
// projection's focal factors; infinity at t_ndc = 1. rays: the scene-frame rays (B,3);
// t_ndc: (B) or (B,1) in [0, 1); the result has t_ndc's shape.
torch::Tensor depth_from_ndc(const Rays& rays, const torch::Tensor& t_ndc);

}  // namespace ablenerf
