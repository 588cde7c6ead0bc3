// Scene normalisation (data/scene_frame): on camera layouts whose answer is known by construction
// (cameras on a tilted ring looking at a point, parallel forward-facing cameras, all cameras at one
// point), the frame's centre, up, scale and bounds, the pose round trip and the JSON round trip.
#include "data/scene_frame.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "test_geometry.h"
#include "test_util.h"
#include "util/errors.h"
#include "data/data_config.h"

using namespace ablenerf;

namespace {

using test::cross3;
using test::dot3;
using test::sub3;
using test::unit3;
using test::V3;

// OpenGL camera-to-world pose at `eye` looking at `target` with world up `up`.
Pose34 look_at_pose(const V3& eye, const V3& target, const V3& up) {
  const test::Frame3 f = test::look_at(eye, target, up);
  Pose34 p{};
  for (size_t r = 0; r < 3; ++r) {
    p[r * 4 + 0] = static_cast<float>(f.right[r]);
    p[r * 4 + 1] = static_cast<float>(f.up[r]);
    p[r * 4 + 2] = static_cast<float>(f.back[r]);
    p[r * 4 + 3] = static_cast<float>(f.eye[r]);
  }
  return p;
}

Capture capture_of(const std::vector<Pose34>& poses) {
  Capture cap;
  cap.format = "instant-ngp";
  CaptureSplit s{"train", "transforms.json", {}};
  for (const auto& p : poses) {
    CaptureFrame f;
    f.pose = p;
    s.frames.push_back(f);
  }
  cap.splits.push_back(s);
  return cap;
}

// Cameras on a circle of radius `radius` around `target` in the plane normal to `up`, `height`
// above it, all looking at `target`.
std::vector<Pose34> ring_poses(int n, const V3& target, const V3& up, double radius, double height) {
  const V3 u = unit3(up), a = unit3(cross3(u, {0.5, 0.2, 0.1})), b = cross3(u, a);
  std::vector<Pose34> out;
  for (int i = 0; i < n; ++i) {
    const double th = 2 * M_PI * i / n + 0.3;
    V3 eye;
    for (size_t c = 0; c < 3; ++c)
      eye[c] = target[c] + radius * (std::cos(th) * a[c] + std::sin(th) * b[c]) + height * u[c];
    out.push_back(look_at_pose(eye, target, up));
  }
  return out;
}

V3 col(const Pose34& p, size_t c) { return {p[c], p[4 + c], p[8 + c]}; }

}  // namespace

TEST(SceneFrame, RingAroundATiltedTargetIsCentredUprightAndUnitSized) {
  const V3 target{5, -2, 7}, up = unit3({0.3, 0.4, 1.0});
  const auto poses = ring_poses(12, target, up, 3.0, 1.0);
  const SceneFrame f = fit_scene_frame(capture_of(poses), "cap", SceneKind::Auto, 2, 6, false);
  EXPECT_EQ(f.kind, SceneKind::Unbounded);  // auto: a real capture is unbounded
  EXPECT_FALSE(f.faces_one_way);            // cameras all round their target
  // The cameras look at `target`: it becomes the origin.
  for (size_t c = 0; c < 3; ++c) EXPECT_NEAR(f.centre[c], target[c], 1e-5);
  // Every camera is sqrt(3^2 + 1^2) from the target: scale puts them on the unit sphere.
  EXPECT_NEAR(f.scale, 1 / std::sqrt(10.0), 1e-6);
  // The ring's up (the mean of the cameras' up vectors is along `up`) becomes +z, and the ring
  // lies in the plane z = 1/sqrt(10).
  const V3 up_scene = f.point_to_scene({target[0] + up[0], target[1] + up[1], target[2] + up[2]});
  EXPECT_NEAR(up_scene[2], f.scale, 1e-6);
  EXPECT_NEAR(std::hypot(up_scene[0], up_scene[1]), 0, 1e-6);
  for (const auto& p : poses) {
    const Pose34 s = f.to_scene(p);
    EXPECT_NEAR(s[11], 1 / std::sqrt(10.0), 1e-5);
    EXPECT_NEAR(std::sqrt(dot3(col(s, 3), col(s, 3))), 1.0, 1e-5);
    // Rotations stay rotations, and to_capture undoes to_scene.
    EXPECT_NEAR(dot3(col(s, 0), col(s, 1)), 0, 1e-6);
    const Pose34 back = f.to_capture(s);
    for (size_t k = 0; k < 12; ++k) EXPECT_NEAR(back[k], p[k], 1e-5);
  }
  // Only cameras: near/far fixed in scene units; unbounded: far stands for infinity.
  EXPECT_EQ(f.bounds_source, "cameras");
  EXPECT_DOUBLE_EQ(f.far, kUnboundedFar);
  const SceneFrame bounded = fit_scene_frame(capture_of(poses), "cap", SceneKind::Bounded, 2, 6, false);
  EXPECT_EQ(bounded.kind, SceneKind::Bounded);
  EXPECT_LT(bounded.far, 10);
}

TEST(SceneFrame, BoundsFromPointsLlffBoundsOrConfig) {
  const V3 target{0, 0, 0}, up{0, 0, 1};
  const auto poses = ring_poses(8, target, up, 4.0, 3.0);  // every camera 5 units away
  Capture cap = capture_of(poses);
  // One sparse point at the target: every camera sees it 5 units ahead (1 in scene units), so
  // near = 0.5 and far = 1.5 (the loader's margins on the 1% / 99% depths).
  cap.points = {{0, 0, 0}};
  SceneFrame f = fit_scene_frame(cap, "cap", SceneKind::Bounded, 2, 6, false);
  EXPECT_EQ(f.bounds_source, "points");
  EXPECT_NEAR(f.near, 0.5, 1e-6);
  EXPECT_NEAR(f.far, 1.5, 1e-6);
  // Points behind every camera only: refused, naming the points.
  Capture behind = capture_of(poses);
  behind.points = {{0, 0, 1000}};
  test::expect_input_error([&] { fit_scene_frame(behind, "cap", SceneKind::Bounded, 2, 6, false); }, "cap", "points",
                           "", true);
  // LLFF bounds (capture units) scaled with margins 0.9 / 1.1.
  Capture llff = capture_of(poses);
  llff.bounds = {{2.5, 7.0}, {3.0, 9.0}};
  f = fit_scene_frame(llff, "cap", SceneKind::Bounded, 2, 6, false);
  EXPECT_EQ(f.bounds_source, "llff bounds");
  EXPECT_NEAR(f.near, 0.9 * 2.5 / 5, 1e-6);
  EXPECT_NEAR(f.far, 1.1 * 9.0 / 5, 1e-6);
  // data.bounds_from_config wins over what the capture says.
  f = fit_scene_frame(llff, "cap", SceneKind::Bounded, 0.3, 2.5, true);
  EXPECT_EQ(f.bounds_source, "config");
  EXPECT_DOUBLE_EQ(f.near, 0.3);
  EXPECT_DOUBLE_EQ(f.far, 2.5);
}

TEST(SceneFrame, ParallelCamerasCentreOnTheirMean) {
  // A forward-facing row of cameras all looking down -y: no common focus, so the centre is the
  // mean camera position and the farthest camera sits at distance 1.
  std::vector<Pose34> poses;
  for (int i = 0; i < 5; ++i) poses.push_back(look_at_pose({1.0 + i, 3, 2}, {1.0 + i, -10, 2}, {0, 0, 1}));
  const SceneFrame f = fit_scene_frame(capture_of(poses), "cap", SceneKind::Auto, 2, 6, false);
  EXPECT_NEAR(f.centre[0], 3, 1e-6);
  EXPECT_NEAR(f.centre[1], 3, 1e-6);
  EXPECT_NEAR(f.centre[2], 2, 1e-6);
  EXPECT_NEAR(f.scale, 0.5, 1e-6);
}

// A room photographed from inside: cameras on a small ring at its middle, each looking straight out
// (their optical axes all meet at the ring's centre, behind every camera), sparse points on the
// room's walls, floor and ceiling. The centre is the cameras' mean, and the unit sphere holds half
// the points (the median point distance, computed here), not just the cameras; without points the
// cameras' sphere stays.
TEST(SceneFrame, CamerasLookingOutOfARoomFitTheRoomNotTheCameras) {
  const V3 middle{1, 2, 1.5};
  std::vector<Pose34> poses;
  for (int i = 0; i < 10; ++i) {
    const double th = 2 * M_PI * i / 10 + 0.1;
    const V3 eye{middle[0] + 0.3 * std::cos(th), middle[1] + 0.3 * std::sin(th), middle[2]};
    const V3 out{middle[0] + 10 * std::cos(th), middle[1] + 10 * std::sin(th), middle[2]};
    poses.push_back(look_at_pose(eye, out, {0, 0, 1}));
  }
  Capture cap = capture_of(poses);
  // The room: x in [-2, 4], y in [0, 4], z in [0, 3]; points on a 0.5 grid over its six faces.
  std::vector<double> distances;
  const double lo[3] = {-2, 0, 0}, hi[3] = {4, 4, 3};
  for (int axis = 0; axis < 3; ++axis)
    for (const double side : {lo[axis], hi[axis]}) {
      const int a = (axis + 1) % 3, b = (axis + 2) % 3;
      for (double u = lo[a]; u <= hi[a] + 1e-9; u += 0.5)
        for (double v = lo[b]; v <= hi[b] + 1e-9; v += 0.5) {
          std::array<double, 3> p{};
          p[static_cast<size_t>(axis)] = side;
          p[static_cast<size_t>(a)] = u;
          p[static_cast<size_t>(b)] = v;
          cap.points.push_back(p);
          distances.push_back(std::sqrt(dot3(sub3({p[0], p[1], p[2]}, middle), sub3({p[0], p[1], p[2]}, middle))));
        }
    }
  std::sort(distances.begin(), distances.end());
  const double median = distances[(distances.size() - 1) / 2];
  ASSERT_GT(median, 1.5);  // well beyond the cameras' 0.3
  const SceneFrame f = fit_scene_frame(cap, "cap", SceneKind::Auto, 2, 6, false);
  EXPECT_TRUE(f.looks_outward);
  EXPECT_FALSE(f.faces_one_way);
  EXPECT_EQ(f.kind, SceneKind::Unbounded);
  for (size_t c = 0; c < 3; ++c) EXPECT_NEAR(f.centre[c], middle[c], 1e-5);
  EXPECT_NEAR(f.scale, 1 / median, 1e-9);
  EXPECT_NE(f.describe().find("looking outward"), std::string::npos);
  EXPECT_TRUE(SceneFrame::from_json(f.to_json(), "scene.json").looks_outward);
  // The nearest wall is 2 units from the middle (y = 0 and y = 4): the near bound is under it.
  EXPECT_LT(f.near, 2 * f.scale);
  // Without points: the cameras' sphere, as for any capture.
  const SceneFrame bare = fit_scene_frame(capture_of(poses), "cap", SceneKind::Auto, 2, 6, false);
  EXPECT_TRUE(bare.looks_outward);
  EXPECT_NEAR(bare.scale, 1 / 0.3, 1e-4);
  // Cameras round an object, and a forward-facing row, do not look outward.
  EXPECT_FALSE(
      fit_scene_frame(capture_of(ring_poses(8, {0, 0, 0}, {0, 0, 1}, 3, 1)), "cap", SceneKind::Auto, 2, 6, false)
          .looks_outward);
  std::vector<Pose34> row;
  for (int i = 0; i < 5; ++i) row.push_back(look_at_pose({1.0 + i, 3, 2}, {1.0 + i, -10, 2}, {0, 0, 1}));
  EXPECT_FALSE(fit_scene_frame(capture_of(row), "cap", SceneKind::Auto, 2, 6, false).looks_outward);
}

TEST(SceneFrame, DegenerateLayoutsAndSyntheticScenes) {
  std::vector<Pose34> same(4, look_at_pose({1, 2, 3}, {0, 0, 0}, {0, 0, 1}));
  test::expect_input_error([&] { fit_scene_frame(capture_of(same), "cap", SceneKind::Auto, 2, 6, false); }, "cap",
                           "poses", "same point", true);
  // Blender scenes keep the identity and the configured near/far.
  Capture blender = capture_of(ring_poses(4, {0, 0, 0}, {0, 0, 1}, 4, 0));
  blender.synthetic = true;
  const SceneFrame f = fit_scene_frame(blender, "cap", SceneKind::Auto, 2, 6, false);
  EXPECT_TRUE(f.identity());
  EXPECT_EQ(f.kind, SceneKind::Bounded);
  EXPECT_DOUBLE_EQ(f.near, 2);
  EXPECT_DOUBLE_EQ(f.far, 6);
}

TEST(SceneFrame, JsonRoundTripAndRefusals) {
  const SceneFrame f = fit_scene_frame(capture_of(ring_poses(6, {1, 2, 3}, {0.1, 0.2, 1}, 2, 1)), "cap",
                                       SceneKind::Bounded, 2, 6, false);
  const SceneFrame g = SceneFrame::from_json(f.to_json(), "scene.json");
  EXPECT_EQ(g.rotation, f.rotation);
  EXPECT_EQ(g.centre, f.centre);
  EXPECT_EQ(g.scale, f.scale);
  EXPECT_EQ(g.kind, f.kind);
  EXPECT_EQ(g.near, f.near);
  EXPECT_EQ(g.far, f.far);
  EXPECT_EQ(g.bounds_source, f.bounds_source);
  test::expect_input_error([] { SceneFrame::from_json("{\"scale\": 1}", "scene.json"); }, "scene.json", "",
                           "not a scene frame", true);
  std::string bad = f.to_json();
  bad.replace(bad.find("\"scale\""), 7, "\"scale\": -1, \"x\"");
  test::expect_input_error([&] { SceneFrame::from_json(bad, "scene.json"); }, "scene.json", "scale", "positive", true);
}

TEST(SceneFrame, ForwardFacingLayoutGetsTheNdcFrame) {
  // A 3x3 grid of cameras in the plane y = -2, all looking at points 5..9 units ahead along +y
  // (within 10 degrees of each other), world up +z: LLFF's layout.
  std::vector<Pose34> poses;
  for (int i = -1; i <= 1; ++i)
    for (int j = -1; j <= 1; ++j)
      poses.push_back(look_at_pose({0.3 * i, -2, 1 + 0.2 * j}, {0.3 * i * 0.5, 5, 1}, {0, 0, 1}));
  Capture cap = capture_of(poses);
  for (auto& f : cap.splits[0].frames) f.camera.width = 40, f.camera.height = 30, f.camera.fx = 35, f.camera.fy = 33;
  cap.points = {{0, 3, 1}, {0.5, 5, 1.2}, {-0.4, 7, 0.8}};  // depths 5..9 from the grid
  const SceneFrame f = fit_scene_frame(cap, "cap", SceneKind::Auto, 2, 6, false);
  ASSERT_EQ(f.kind, SceneKind::ForwardFacing);
  EXPECT_TRUE(f.faces_one_way);
  EXPECT_DOUBLE_EQ(f.near, 0);
  EXPECT_DOUBLE_EQ(f.far, 1);
  EXPECT_NEAR(f.ndc_a, 70.0 / 40, 1e-12);
  EXPECT_NEAR(f.ndc_b, 66.0 / 30, 1e-12);
  // Centred on the mean camera, looking down -z with +z (world up) towards +y.
  for (size_t c = 0; c < 3; ++c) EXPECT_NEAR(f.centre[c], (V3{0, -2, 1})[c], 1e-6);
  const V3 ahead = f.point_to_scene({0, 5, 1});
  EXPECT_NEAR(ahead[0], 0, 1e-3);
  EXPECT_LT(ahead[2], 0);
  const V3 above = f.point_to_scene({0, -2, 2});
  EXPECT_GT(above[1], 0);
  EXPECT_NEAR(above[0], 0, 1e-3);
  // The nearest content (~5 units ahead: the 1st percentile of the points' depths) at 1 / 0.75.
  EXPECT_NEAR(-f.point_to_scene({0, 3, 1})[2], 1 / 0.75, 0.05);
  // Round trip through scene.json keeps the projection.
  const SceneFrame g = SceneFrame::from_json(f.to_json(), "scene.json");
  EXPECT_EQ(g.kind, SceneKind::ForwardFacing);
  EXPECT_EQ(g.ndc_a, f.ndc_a);
  // With data.ndc = false auto fits the same capture as an unbounded scene, and forward is still
  // there to be asked for.
  const SceneFrame u = fit_scene_frame(cap, "cap", SceneKind::Auto, 2, 6, false, /*auto_ndc=*/false);
  EXPECT_EQ(u.kind, SceneKind::Unbounded);
  EXPECT_EQ(u.far, kUnboundedFar);
  // Contracted, it keeps its layout (through scene.json too; a scene.json written before the key
  // was kept reads it from the kind).
  EXPECT_TRUE(u.faces_one_way);
  EXPECT_TRUE(SceneFrame::from_json(u.to_json(), "scene.json").faces_one_way);
  EXPECT_NE(u.describe().find("cameras facing one way"), std::string::npos) << u.describe();
  std::string old_json = u.to_json();
  old_json.replace(old_json.find("\"faces_one_way\": true"), 21, "\"x\": 0");
  EXPECT_FALSE(SceneFrame::from_json(old_json, "scene.json").faces_one_way);
  old_json = f.to_json();
  old_json.replace(old_json.find("\"faces_one_way\": true"), 21, "\"x\": 0");
  EXPECT_TRUE(SceneFrame::from_json(old_json, "scene.json").faces_one_way);
  EXPECT_EQ(fit_scene_frame(cap, "cap", SceneKind::ForwardFacing, 2, 6, false, false).kind, SceneKind::ForwardFacing);
  // Without points or bounds auto stays unbounded, and an explicit forward is refused.
  const Capture bare = capture_of(poses);
  EXPECT_EQ(fit_scene_frame(bare, "cap", SceneKind::Auto, 2, 6, false).kind, SceneKind::Unbounded);
  test::expect_input_error([&] { fit_scene_frame(bare, "cap", SceneKind::ForwardFacing, 2, 6, false); }, "cap",
                           "data.scene", "near bound", true);
  // Cameras all round the scene are not forward-facing, even with points; forcing it is refused.
  Capture round = capture_of(ring_poses(8, {0, 0, 0}, {0, 0, 1}, 3, 1));
  round.points = {{0, 0, 0}};
  EXPECT_EQ(fit_scene_frame(round, "cap", SceneKind::Auto, 2, 6, false).kind, SceneKind::Unbounded);
  EXPECT_FALSE(fit_scene_frame(round, "cap", SceneKind::Auto, 2, 6, false).faces_one_way);
  test::expect_input_error([&] { fit_scene_frame(round, "cap", SceneKind::ForwardFacing, 2, 6, false); }, "cap",
                           "data.scene", "same way", true);
}

// data.scene_centre and data.scene_radius on a rig whose answers are known: 8 cameras on a ring of
// radius 4, 3 above their target (every camera 5 from it), so the focus is the target and the mean
// camera sits 3 above it; the sources named in the frame and its JSON.
TEST(SceneFrame, CentreAndRadiusFromTheConfig) {
  const V3 target{1, -2, 0.5}, up{0, 0, 1};
  const Capture cap = capture_of(ring_poses(8, target, up, 4.0, 3.0));
  const SceneFrame chosen = fit_scene_frame(cap, "cap", SceneKind::Auto, 2, 6, false);
  EXPECT_EQ(chosen.centre_source, "focus");
  EXPECT_EQ(chosen.radius_source, "farthest camera");
  EXPECT_NEAR(chosen.scale, 1 / 5.0, 1e-6);
  // The mean camera: 3 above the target; the farthest camera then 4 away.
  SceneFrame f = fit_scene_frame(cap, "cap", SceneKind::Auto, 2, 6, false, true, {SceneCentre::Cameras, 0});
  EXPECT_NEAR(f.centre[0], target[0], 1e-6);
  EXPECT_NEAR(f.centre[1], target[1], 1e-6);
  EXPECT_NEAR(f.centre[2], target[2] + 3, 1e-6);
  EXPECT_NEAR(f.scale, 1 / 4.0, 1e-6);
  EXPECT_EQ(f.centre_source, "cameras (data.scene_centre)");
  EXPECT_NE(f.describe().find("cameras (data.scene_centre)"), std::string::npos);
  // A radius in the capture's units: 10 units become 1, the cameras at 0.5.
  f = fit_scene_frame(cap, "cap", SceneKind::Auto, 2, 6, false, true, {SceneCentre::Focus, 10});
  for (size_t c = 0; c < 3; ++c) EXPECT_NEAR(f.centre[c], target[c], 1e-5);
  EXPECT_DOUBLE_EQ(f.scale, 0.1);
  EXPECT_EQ(f.radius_source, "data.scene_radius");
  const Pose34 first = f.to_scene(ring_poses(8, target, up, 4.0, 3.0).front());
  EXPECT_NEAR(std::sqrt(first[3] * first[3] + first[7] * first[7] + first[11] * first[11]), 0.5, 1e-5);
  const SceneFrame back = SceneFrame::from_json(f.to_json(), "scene.json");
  EXPECT_EQ(back.centre_source, "focus (data.scene_centre)");
  EXPECT_EQ(back.radius_source, "data.scene_radius");
  // Parallel cameras have no focus: "focus" refused, naming the key; "cameras" is their auto choice.
  std::vector<Pose34> row;
  for (int i = 0; i < 5; ++i) row.push_back(look_at_pose({1.0 + i, 3, 2}, {1.0 + i, -10, 2}, {0, 0, 1}));
  test::expect_input_error(
      [&] {
        fit_scene_frame(capture_of(row), "cap", SceneKind::Auto, 2, 6, false, true, {SceneCentre::Focus, 0});
      },
      "cap", "data.scene_centre", "parallel", true);
  // A forward-facing capture with LLFF bounds: `auto` takes NDC rays, but not with an override.
  Capture llff = capture_of(row);
  llff.bounds = std::vector<std::array<double, 2>>(5, {2.0, 20.0});
  EXPECT_EQ(fit_scene_frame(llff, "cap", SceneKind::Auto, 2, 6, false).kind, SceneKind::ForwardFacing);
  f = fit_scene_frame(llff, "cap", SceneKind::Auto, 2, 6, false, true, {SceneCentre::Auto, 7});
  EXPECT_EQ(f.kind, SceneKind::Unbounded);
  EXPECT_DOUBLE_EQ(f.scale, 1 / 7.0);
  // Refused where the frame is fixed: `forward`, and Blender scenes.
  test::expect_input_error(
      [&] {
        fit_scene_frame(llff, "cap", SceneKind::ForwardFacing, 2, 6, false, true, {SceneCentre::Cameras, 0});
      },
      "cap", "data.scene_centre", "forward", true);
  Capture blender = cap;
  blender.synthetic = true;
  test::expect_input_error(
      [&] {
        fit_scene_frame(blender, "cap", SceneKind::Auto, 2, 6, false, true, {SceneCentre::Auto, 3});
      },
      "cap", "data.scene_radius", "Blender", true);
}
