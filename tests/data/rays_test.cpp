// Cameras and rays (docs/MODEL.md, section 1) against hand-computed values.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>

#include "data/rays.h"

using namespace ablenerf;

namespace {
Intrinsics blender_like(int w, int h, double angle_x) {
  Intrinsics k;
  k.width = w;
  k.height = h;
  k.fx = k.fy = 0.5 * w / std::tan(0.5 * angle_x);
  k.cx = 0.5 * w;
  k.cy = 0.5 * h;
  return k;
}
}  // namespace

TEST(Rays, IdentityCameraPixelCentres) {
  // 4x2 image, focal 2 (hand-chosen): pixel (col 0,row 0) centre is (0.5,0.5), principal point (2,1).
  Intrinsics k;
  k.width = 4;
  k.height = 2;
  k.fx = k.fy = 2.0;
  k.cx = 2.0;
  k.cy = 1.0;
  auto c2w = torch::eye(4).slice(0, 0, 3);  // identity pose
  Rays r = rays_for_image(c2w, k);
  ASSERT_EQ(r.size(), 8);
  // Row-major: ray 0 = (col 0, row 0): x = (0.5-2)/2 = -0.75, y = -(0.5-1)/2 = 0.25, z = -1.
  EXPECT_FLOAT_EQ(r.directions[0][0].item<float>(), -0.75f);
  EXPECT_FLOAT_EQ(r.directions[0][1].item<float>(), 0.25f);
  EXPECT_FLOAT_EQ(r.directions[0][2].item<float>(), -1.0f);
  // ray 7 = (col 3, row 1): x = (3.5-2)/2 = 0.75, y = -(1.5-1)/2 = -0.25.
  EXPECT_FLOAT_EQ(r.directions[7][0].item<float>(), 0.75f);
  EXPECT_FLOAT_EQ(r.directions[7][1].item<float>(), -0.25f);
  EXPECT_TRUE(torch::all(r.origins == 0).item<bool>());
  // radius = 2 / (sqrt(12) f) = 1/(sqrt(3)*2)
  EXPECT_NEAR(r.radii[3][0].item<float>(), 1.0 / (std::sqrt(3.0) * 2.0), 1e-7);
}

TEST(Rays, RotatedTranslatedCamera) {
  // Camera at (1,2,3), rotated 90 degrees about +y: camera -z axis maps to world -x.
  Intrinsics k = blender_like(2, 2, 2 * std::atan(0.5));  // f = 0.5*2/0.5 = 2
  EXPECT_NEAR(k.fx, 2.0, 1e-12);
  // R = rot_y(90deg): x' = z, z' = -x  -> columns: R*e_x = (0,0,-1), R*e_y = (0,1,0), R*e_z = (1,0,0)
  auto c2w = torch::tensor({0.f, 0.f, 1.f, 1.f, 0.f, 1.f, 0.f, 2.f, -1.f, 0.f, 0.f, 3.f}).reshape({3, 4});
  Rays r = rays_for_image(c2w, k);
  // pixel (col 1,row 0): d_cam = ((1.5-1)/2, -(0.5-1)/2, -1) = (0.25, 0.25, -1)
  // world = R d_cam = (z, y, -x) = (-1, 0.25, -0.25)
  EXPECT_FLOAT_EQ(r.directions[1][0].item<float>(), -1.0f);
  EXPECT_FLOAT_EQ(r.directions[1][1].item<float>(), 0.25f);
  EXPECT_FLOAT_EQ(r.directions[1][2].item<float>(), -0.25f);
  EXPECT_FLOAT_EQ(r.origins[1][0].item<float>(), 1.0f);
  EXPECT_FLOAT_EQ(r.origins[1][1].item<float>(), 2.0f);
  EXPECT_FLOAT_EQ(r.origins[1][2].item<float>(), 3.0f);
}

TEST(Rays, RadiusMatchesNeighbourDistanceRule) {
  // The mip-NeRF rule: ||d[j,i] - d[j+1,i]|| * 2/sqrt(12), computed here from the directions.
  Intrinsics k = blender_like(800, 800, 0.6911112070083618);
  EXPECT_NEAR(k.fx, 1111.1110311937682, 1e-6);
  auto c2w = torch::tensor({0.8f, 0.36f, -0.48f, 1.f, -0.6f, 0.48f, -0.64f, 2.f, 0.f, 0.8f, 0.6f, 3.f}).reshape({3, 4});
  auto col = torch::tensor({10, 10});
  auto row = torch::tensor({20, 21});
  Rays r = rays_for_pixels(c2w.unsqueeze(0).expand({2, 3, 4}), col, row, k);
  const double dx = (r.directions[0] - r.directions[1]).norm().item<double>();
  EXPECT_NEAR(r.radii[0][0].item<double>(), dx * 2.0 / std::sqrt(12.0), 1e-8);
  EXPECT_NEAR(r.radii[0][0].item<double>(), 5.196152e-4, 1e-9);
  // camera-frame z of the direction is exactly -1: R^T d has z = -1
  auto dcam = torch::matmul(c2w.slice(1, 0, 3).t(), r.directions[0]);
  EXPECT_NEAR(dcam[2].item<float>(), -1.0f, 1e-6);
}
