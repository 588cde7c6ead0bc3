// Camera paths: rigid poses, looking at the origin with +z up, at the requested distance and
// elevation; look_at on a hand-worked pose; the rig estimate from known cameras.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <tuple>

#include "data/rays.h"
#include "eval/camera_path.h"
#include "test_util.h"
#include "util/errors.h"

using namespace ablenerf;

namespace {

// Checks rotation orthonormality, det +1, optical axis (-z) through the origin, x horizontal.
void expect_looks_at_origin(const torch::Tensor& pose, double distance) {
  const auto p = pose.to(torch::kDouble);
  const auto rot = p.slice(1, 0, 3), centre = p.select(1, 3);
  EXPECT_TRUE(torch::allclose(rot.t().mm(rot), torch::eye(3, torch::kDouble), 0, 1e-6));
  EXPECT_NEAR(torch::det(rot).item<double>(), 1.0, 1e-6);
  EXPECT_NEAR(centre.norm().item<double>(), distance, 1e-5);
  // Camera z (backwards) must point from the origin to the centre: z == centre / |centre|.
  EXPECT_TRUE(torch::allclose(rot.select(1, 2), centre / centre.norm(), 0, 1e-6));
  // +z up: camera x stays horizontal and camera y has a positive world-z component.
  EXPECT_NEAR(rot[2][0].item<double>(), 0.0, 1e-6);
  EXPECT_GT(rot[2][1].item<double>(), 0.0);
}

}  // namespace

TEST(LookAt, HandWorkedPose) {
  // Eye on -y looking at the origin: camera looks along +y, so z_cam = (0,-1,0), x = up x z =
  // (1,0,0), y = z x x = (0,0,1).
  const auto p = look_at(torch::tensor({0.0, -4.0, 0.0}), torch::zeros({3}), torch::tensor({0.0, 0.0, 1.0}));
  const auto expected = torch::tensor({{1.f, 0.f, 0.f, 0.f}, {0.f, 0.f, -1.f, -4.f}, {0.f, 1.f, 0.f, 0.f}});
  EXPECT_TRUE(torch::allclose(p, expected, 0, 1e-6)) << p;
  EXPECT_THROW(look_at(torch::tensor({0.0, 0.0, 3.0}), torch::zeros({3}), torch::tensor({0.0, 0.0, 1.0})),
               std::invalid_argument);
}

TEST(CameraPath, OrbitIsACircleAtTheRigElevation) {
  const CameraRig rig{4.0, 0.5};
  const auto poses = camera_path(PathKind::Orbit, 12, rig);
  ASSERT_EQ(poses.sizes(), (std::vector<int64_t>{12, 3, 4}));
  for (int i = 0; i < 12; ++i) {
    expect_looks_at_origin(poses[i], 4.0);
    EXPECT_NEAR(std::asin(poses[i][2][3].item<double>() / 4.0), 0.5, 1e-5);
  }
  // Evenly spaced azimuths: consecutive centres are 30 degrees apart around z.
  const auto c0 = poses[0].select(1, 3), c1 = poses[1].select(1, 3);
  const double az0 = std::atan2(c0[1].item<double>(), c0[0].item<double>());
  const double az1 = std::atan2(c1[1].item<double>(), c1[0].item<double>());
  EXPECT_NEAR(az1 - az0, 2 * M_PI / 12, 1e-5);
}

TEST(CameraPath, SpiralKeepsDistanceAndSwingsElevation) {
  const CameraRig rig{3.0, 0.3};
  const auto poses = camera_path(PathKind::Spiral, 40, rig);
  double lo = 10, hi = -10;
  for (int i = 0; i < 40; ++i) {
    expect_looks_at_origin(poses[i], 3.0);
    const double el = std::asin(poses[i][2][3].item<double>() / 3.0);
    lo = std::min(lo, el), hi = std::max(hi, el);
  }
  // 40 frames, 2 cycles: samples land exactly on the sine's peaks (k = 5, 15, ...).
  EXPECT_NEAR(hi, 0.3 + kSpiralAmplitudeRad, 1e-5);
  EXPECT_NEAR(lo, 0.3 - kSpiralAmplitudeRad, 1e-5);
}

TEST(CameraPath, ElevationIsClampedBelowThePole) {
  const auto poses = camera_path(PathKind::Spiral, 8, CameraRig{2.0, 1.5});
  for (int i = 0; i < 8; ++i) expect_looks_at_origin(poses[i], 2.0);
}

TEST(CameraPath, CentrePixelRayPassesThroughTheOrigin) {
  // Ties the poses to the ray convention of data/rays.h: the principal ray hits the origin.
  Intrinsics k;
  k.width = k.height = 2;
  k.fx = k.fy = 1;
  k.cx = k.cy = 1;  // pixel centres at +-0.5: average of the four rays is the optical axis
  const auto pose = camera_path(PathKind::Orbit, 5, CameraRig{4.0, 0.7})[2];
  const Rays r = rays_for_image(pose, k);
  const auto axis = r.directions.mean(0).to(torch::kDouble);
  const auto o = r.origins[0].to(torch::kDouble);
  // Distance from the origin to the line o + s * axis.
  const auto closest = o - axis * (o.dot(axis) / axis.dot(axis));
  EXPECT_LT(closest.norm().item<double>(), 1e-5);
}

TEST(CameraRigTest, MeanDistanceAndElevationOfKnownCameras) {
  const auto up = torch::tensor({0.0, 0.0, 1.0});
  std::vector<torch::Tensor> poses;
  // Two cameras at distance 3 (elevation 0.2, 0.6) and one at distance 6 (elevation 0.4).
  for (auto [d, el, az] :
       std::initializer_list<std::tuple<double, double, double>>{{3.0, 0.2, 0.0}, {3.0, 0.6, 1.0}, {6.0, 0.4, 2.0}})
    poses.push_back(
        look_at(torch::tensor({d * std::cos(el) * std::cos(az), d * std::cos(el) * std::sin(az), d * std::sin(el)}),
                torch::zeros({3}), up));
  const CameraRig rig = camera_rig(torch::stack(poses));
  EXPECT_NEAR(rig.distance, 4.0, 1e-5);
  EXPECT_NEAR(rig.elevation, 0.4, 1e-5);
}

TEST(CameraPath, StaysInsideTheArcAndElevationsTheCamerasCover) {
  const auto up = torch::tensor({0.0, 0.0, 1.0});
  const auto ring = [&](const std::vector<double>& azimuths_deg, const std::vector<double>& elevations) {
    std::vector<torch::Tensor> poses;
    for (size_t i = 0; i < azimuths_deg.size(); ++i) {
      const double az = azimuths_deg[i] * M_PI / 180, el = elevations[i % elevations.size()];
      poses.push_back(
          look_at(torch::tensor({2 * std::cos(el) * std::cos(az), 2 * std::cos(el) * std::sin(az), 2 * std::sin(el)}),
                  torch::zeros({3}), up));
    }
    return torch::stack(poses);
  };
  // A capture that went from -60 to +80 degrees of azimuth (given out of order), 0.1 to 0.3 rad up.
  const CameraRig arc = camera_rig(ring({20, -60, 80, -10, 45, -35}, {0.1, 0.3, 0.2}));
  EXPECT_FALSE(arc.full_circle());
  EXPECT_NEAR(arc.azimuth_start, -60 * M_PI / 180, 1e-6);
  EXPECT_NEAR(arc.azimuth_span, 140 * M_PI / 180, 1e-6);
  EXPECT_NEAR(arc.elevation_min, 0.1, 1e-6);
  EXPECT_NEAR(arc.elevation_max, 0.3, 1e-6);
  const int n = 40;
  for (const PathKind kind : {PathKind::Orbit, PathKind::Spiral}) {
    const auto centres = camera_path(kind, n, arc).select(2, 3).to(torch::kDouble);
    const auto az = torch::atan2(centres.select(1, 1), centres.select(1, 0)) * (180 / M_PI);
    const auto el = torch::asin(centres.select(1, 2) / centres.norm(2, 1));
    EXPECT_GE(az.min().item<double>(), -60 - 1e-4);
    EXPECT_LE(az.max().item<double>(), 80 + 1e-4);
    EXPECT_NEAR(az[0].item<double>(), -60, 1e-4);                       // starts at one end,
    EXPECT_NEAR(az[n / 2].item<double>(), 80, 1e-4);                    // reaches the other at mid-video,
    EXPECT_NEAR(az[n - 1].item<double>(), az[1].item<double>(), 1e-4);  // and comes back: the video loops
    EXPECT_GE(el.min().item<double>(), 0.1 - 1e-6);
    EXPECT_LE(el.max().item<double>(), 0.3 + 1e-6);
  }
  // The spiral's swing shrinks to the 0.1 rad the cameras allow around their mean elevation 0.2.
  const auto spiral = camera_path(PathKind::Spiral, n, arc).select(2, 3).to(torch::kDouble);
  EXPECT_NEAR(torch::asin(spiral.select(1, 2) / spiral.norm(2, 1)).max().item<double>(), 0.2 + 0.1, 1e-3);
  // Cameras all the way round (largest gap 60 degrees): the full circle, as before.
  const CameraRig round = camera_rig(ring({0, 60, 120, 180, 240, 300}, {0.4}));
  EXPECT_TRUE(round.full_circle());
  const auto c = camera_path(PathKind::Orbit, 4, round).select(2, 3);
  EXPECT_NEAR(c[1][1].item<double>() / c[1].norm().item<double>(), std::cos(0.4), 1e-5);  // azimuth 90 degrees
}

TEST(CameraPath, RecordedPathFiles) {
  test::TempDir t;
  const std::string ok =
      "{\"ablenerf_path\": 1, \"coordinates\": \"scene\", \"poses\": "
      "[[1,0,0,0.5, 0,1,0,-1, 0,0,1,2], [0,-1,0,0, 1,0,0,0, 0,0,1,3]]}";
  test::write_file(t / "p.json", ok);
  EXPECT_TRUE(is_path_file(t / "p.json"));
  EXPECT_FALSE(is_path_file("orbit"));
  const auto poses = read_path_file(t / "p.json");
  ASSERT_EQ(poses.sizes(), (std::vector<int64_t>{2, 3, 4}));
  EXPECT_FLOAT_EQ(poses[0][1][3].item<float>(), -1);
  EXPECT_FLOAT_EQ(poses[1][0][1].item<float>(), -1);
  const std::pair<std::string, std::string> bad[] = {
      {"not json", "byte 2"},  // where the parse stopped (util/json_file.h)
      {"{\"ablenerf_path\": 2, \"coordinates\": \"scene\", \"poses\": [[1,0,0,0,0,1,0,0,0,0,1,0]]}", "ablenerf_path"},
      {"{\"ablenerf_path\": 1, \"coordinates\": \"capture\", \"poses\": [[1,0,0,0,0,1,0,0,0,0,1,0]]}", "coordinates"},
      {"{\"ablenerf_path\": 1, \"coordinates\": \"scene\", \"poses\": []}", "poses"},
      {"{\"ablenerf_path\": 1, \"coordinates\": \"scene\", \"poses\": [[1,0,0,0,0,1,0,0,0,0,1]]}", "poses[0]"},
      {"{\"ablenerf_path\": 1, \"coordinates\": \"scene\", \"poses\": [[2,0,0,0,0,1,0,0,0,0,1,0]]}", "poses[0]"},
  };
  for (const auto& [text, field] : bad) {
    test::write_file(t / "bad.json", text);
    test::expect_input_error([&] { read_path_file(t / "bad.json"); }, t / "bad.json", field, "", true);
  }
}

TEST(CameraPath, ParseKind) {
  EXPECT_EQ(parse_path_kind("orbit"), PathKind::Orbit);
  EXPECT_EQ(parse_path_kind("spiral"), PathKind::Spiral);
  EXPECT_THROW(parse_path_kind("helix"), InputError);
}
