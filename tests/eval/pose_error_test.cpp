// Camera pose errors (eval/pose_error.h) against hand-worked cases: a camera turned about its own
// centre by a known angle, one moved by a known shift, the reprojection angle of a point straight
// ahead, and a whole rig moved by one rigid motion, which the alignment takes back exactly.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>

#include "eval/pose_error.h"

namespace ablenerf {
namespace {

// A (3,4) camera-to-world: rotation about the world y axis by `deg` degrees, centre c.
torch::Tensor turned_camera(double deg, const torch::Tensor& c) {
  const double a = deg * M_PI / 180.0;
  auto p = torch::zeros({3, 4}, torch::kDouble);
  p[0][0] = std::cos(a), p[0][2] = std::sin(a), p[1][1] = 1.0, p[2][0] = -std::sin(a), p[2][2] = std::cos(a);
  p.select(1, 3).copy_(c);
  return p;
}

TEST(PoseError, TurnShiftAndReprojectionByHand) {
  const auto centre = torch::tensor({0.0, 0.0, 4.0}, torch::kDouble);
  const auto truth = turned_camera(0.0, centre).unsqueeze(0);  // looks down -z at the origin
  const auto origin = torch::zeros({1, 3}, torch::kDouble);
  // Turned by 2 degrees about its centre: the origin is seen 2 degrees off, the centre unmoved.
  const PoseErrors turned = pose_errors(turned_camera(2.0, centre).unsqueeze(0), truth, origin);
  EXPECT_NEAR(turned.rotation_deg, 2.0, 1e-9);
  EXPECT_NEAR(turned.centre, 0.0, 1e-12);
  EXPECT_NEAR(turned.reprojection_deg, 2.0, 1e-9);
  // Shifted sideways by 0.1 at distance 4: atan(0.1 / 4) off, no turn.
  const PoseErrors shifted =
      pose_errors(turned_camera(0.0, torch::tensor({0.1, 0.0, 4.0}, torch::kDouble)).unsqueeze(0), truth, origin);
  EXPECT_NEAR(shifted.rotation_deg, 0.0, 1e-6);
  EXPECT_NEAR(shifted.centre, 0.1, 1e-12);
  EXPECT_NEAR(shifted.reprojection_deg, std::atan(0.1 / 4.0) * 180.0 / M_PI, 1e-9);
  // Two cameras: the means.
  const auto both = torch::stack({turned_camera(2.0, centre), turned_camera(0.0, centre)});
  EXPECT_NEAR(pose_errors(both, torch::cat({truth, truth}), origin).rotation_deg, 1.0, 1e-9);
}

TEST(PoseError, ARigMovedByOneRigidMotionAlignsBackExactly) {
  torch::manual_seed(2);
  // Six cameras on a ring around the origin, each looking roughly inwards with its own turn.
  std::vector<torch::Tensor> cams;
  for (int i = 0; i < 6; ++i) {
    const double a = i * M_PI / 3.0;
    cams.push_back(
        turned_camera(i * 60.0 + 7.0 * i, torch::tensor({4 * std::sin(a), 0.3 * i, 4 * std::cos(a)}, torch::kDouble)));
  }
  const auto truth = torch::stack(cams);
  // One rigid motion: 5 degrees about a tilted axis (Rodrigues), then a shift.
  auto axis = torch::tensor({0.3, 1.0, -0.2}, torch::kDouble);
  axis = axis / axis.norm();
  const double th = 5.0 * M_PI / 180.0;
  auto k = torch::zeros({3, 3}, torch::kDouble);
  k[0][1] = -axis[2], k[0][2] = axis[1], k[1][0] = axis[2], k[1][2] = -axis[0], k[2][0] = -axis[1], k[2][1] = axis[0];
  const auto r = torch::eye(3, torch::kDouble) + std::sin(th) * k + (1 - std::cos(th)) * torch::matmul(k, k);
  const auto t = torch::tensor({0.2, -0.1, 0.05}, torch::kDouble);
  auto moved = torch::empty_like(truth);
  moved.slice(2, 0, 3).copy_(torch::matmul(r, truth.slice(2, 0, 3)));
  moved.select(2, 3).copy_(torch::matmul(truth.select(2, 3), r.t()) + t);
  const auto points = box_lattice(torch::full({3}, -0.8, torch::kDouble), torch::full({3}, 0.8, torch::kDouble));
  const PoseErrors before = pose_errors(moved, truth, points);
  EXPECT_NEAR(before.rotation_deg, 5.0, 1e-9);  // every camera turned by the motion's 5 degrees
  EXPECT_GT(before.reprojection_deg, 1.0);
  const auto aligned = align_poses_rigid(moved, truth);
  EXPECT_LT((aligned - truth).abs().max().item<double>(), 1e-9);
  const PoseErrors after = pose_errors(aligned, truth, points);
  EXPECT_LT(after.reprojection_deg, 1e-5);
  EXPECT_LT(after.centre, 1e-9);
}

TEST(PoseError, BoxLatticeSpansTheBox) {
  const auto p =
      box_lattice(torch::tensor({-1.0, 0.0, 2.0}, torch::kDouble), torch::tensor({1.0, 4.0, 3.0}, torch::kDouble));
  ASSERT_EQ(p.sizes(), (std::vector<int64_t>{27, 3}));
  EXPECT_TRUE(torch::allclose(std::get<0>(p.min(0)), torch::tensor({-1.0, 0.0, 2.0}, torch::kDouble)));
  EXPECT_TRUE(torch::allclose(std::get<0>(p.max(0)), torch::tensor({1.0, 4.0, 3.0}, torch::kDouble)));
  EXPECT_TRUE(torch::allclose(p.mean(0), torch::tensor({0.0, 2.0, 2.5}, torch::kDouble)));
}

}  // namespace
}  // namespace ablenerf
