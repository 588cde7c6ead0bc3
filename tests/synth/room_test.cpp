// The room scene (`synth --scene room`), checked against independent references: depth against the
// closed-form distance to the first surface (each wall, furniture face and the ball intersected
// here with plain per-plane math, read from scene.json), the cameras' stated region and directions,
// opaque pixels everywhere, the nerfstudio loader's rays against the renderer's, Lambert shading
// with hard shadows at hand-picked floor points, determinism and the option checks.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>

#include "data/capture.h"
#include "data/dataset.h"
#include "synth/room.h"
#include "synth/room_camera.h"
#include "synth/scene.h"
#include "synth_test_util.h"
#include "loader_rays.h"
#include "test_util.h"
#include "util/errors.h"
#include "util/fs.h"
#include "util/image_io.h"

using namespace ablenerf;
using namespace ablenerf::synth_test;
using nlohmann::json;

// A named namespace (not an anonymous one): test_synth is a unity build, where the other files'
// file-local helpers share this translation unit.
namespace room_test {

constexpr int kRes = 32;
constexpr int kTrain = 4, kTest = 3;
constexpr uint64_t kSeed = 5;

json read_json(const std::string& path) { return json::parse(read_file(path)); }
V3 v3(const json& a) { return {a.at(0).get<double>(), a.at(1).get<double>(), a.at(2).get<double>()}; }

// The room as scene.json describes it: the inside of one box, boxes of furniture and spheres.
struct RoomRef {
  V3 lo, hi;
  std::vector<std::pair<V3, V3>> boxes;        // (min, max)
  std::vector<std::pair<V3, double>> spheres;  // (centre, radius)
};

RoomRef room_from_scene_json(const std::string& dir) {
  const json scene = read_json(dir + "/scene.json");
  EXPECT_EQ(scene.at("scene"), "room");
  RoomRef r;
  r.lo = v3(scene.at("room").at("min"));
  r.hi = v3(scene.at("room").at("max"));
  for (const auto& o : scene.at("objects")) {
    if (o.at("shape") == "box") r.boxes.push_back({v3(o.at("min")), v3(o.at("max"))});
    if (o.at("shape") == "sphere") r.spheres.push_back({v3(o.at("centre")), o.at("radius").get<double>()});
  }
  return r;
}

// The smallest t > 0 at which o + t d meets the plane x_axis = c inside the rectangle [lo, hi] of
// the two other axes, or -1.
double ray_rect(const V3& o, const V3& d, int axis, double c, const V3& lo, const V3& hi) {
  if (d[axis] == 0) return -1;
  const double t = (c - o[axis]) / d[axis];
  if (t <= 0) return -1;
  for (int a = 0; a < 3; ++a) {
    if (a == axis) continue;
    const double x = o[a] + t * d[a];
    if (x < lo[a] - 1e-9 || x > hi[a] + 1e-9) return -1;
  }
  return t;
}

// The analytic distance (in units of |d|) to the first surface: the six faces of the room's
// inside and of each box as rectangles, and the spheres; which = 0 room, 1 furniture box, 2 sphere.
double first_surface(const RoomRef& room, const V3& o, const V3& d, int* which = nullptr) {
  double best = -1;
  const auto take = [&](double t, int kind) {
    if (t > 0 && (best < 0 || t < best)) {
      best = t;
      if (which) *which = kind;
    }
  };
  for (int axis = 0; axis < 3; ++axis)
    for (double c : {room.lo[axis], room.hi[axis]}) take(ray_rect(o, d, axis, c, room.lo, room.hi), 0);
  for (const auto& [lo, hi] : room.boxes)
    for (int axis = 0; axis < 3; ++axis)
      for (double c : {lo[axis], hi[axis]}) take(ray_rect(o, d, axis, c, lo, hi), 1);
  for (const auto& [centre, radius] : room.spheres) take(ray_sphere(o, d, centre, radius), 2);
  return best;
}

// A camera from a nerfstudio transforms.json frame (square pixels, centred principal point).
JsonCamera camera_from_nerfstudio(const json& tj, size_t frame) {
  JsonCamera cam{};
  const auto& tm = tj.at("frames").at(frame).at("transform_matrix");
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) cam.m[r][c] = tm.at(r).at(c).get<double>();
  cam.width = tj.at("w").get<int>();
  cam.height = tj.at("h").get<int>();
  cam.focal = tj.at("fl_x").get<double>();
  EXPECT_DOUBLE_EQ(tj.at("cx").get<double>(), 0.5 * cam.width);
  EXPECT_DOUBLE_EQ(tj.at("fl_y").get<double>(), cam.focal);
  return cam;
}

JsonCamera camera_from_synth(const synth::Camera& c) {
  JsonCamera cam{};
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 4; ++k) cam.m[r][k] = c.c2w[r][k];
  cam.width = c.width;
  cam.height = c.height;
  cam.focal = c.focal;
  return cam;
}

torch::Tensor load_depth(const std::string& path) {
  const std::string bytes = read_file(path);
  return torch::pickle_load(std::vector<char>(bytes.begin(), bytes.end())).toTensor();
}

SynthOptions room_options(int res, int train, int test, uint64_t seed) {
  SynthOptions o;
  o.scene = "room";
  o.res = res;
  o.train_views = train;
  o.test_views = test;
  o.seed = seed;
  o.threads = 2;
  return o;
}

// One small room capture shared by the tests of this file.
class SynthRoom : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    tmp_ = std::make_unique<test::TempDir>("synth_room");
    write_synthetic_dataset(tmp_->path(), room_options(kRes, kTrain, kTest, kSeed));
  }
  static void TearDownTestSuite() { tmp_.reset(); }
  static std::string dir() { return tmp_->path(); }
  static std::unique_ptr<test::TempDir> tmp_;
};
std::unique_ptr<test::TempDir> SynthRoom::tmp_;

TEST_F(SynthRoom, TestDepthIsTheAnalyticDistanceToTheFirstSurface) {
  const RoomRef room = room_from_scene_json(dir());
  ASSERT_EQ(room.boxes.size(), 3u);
  ASSERT_EQ(room.spheres.size(), 1u);
  // The written test views, every pixel's centre ray (depth = t with camera z = -1: along the axis).
  const json tj = read_json(dir() + "/transforms.json");
  for (int k = 0; k < kTest; ++k) {
    const auto depth = load_depth(dir() + "/test/r_" + std::to_string(k) + "_depth.pt");
    ASSERT_EQ(depth.scalar_type(), torch::kFloat);
    ASSERT_EQ(depth.sizes(), (std::vector<int64_t>{kRes, kRes}));
    const auto acc = depth.accessor<float, 2>();
    const JsonCamera cam = camera_from_nerfstudio(tj, static_cast<size_t>(kTrain + k));
    for (int j = 0; j < kRes; ++j)
      for (int i = 0; i < kRes; ++i) {
        const double want = first_surface(room, cam.origin(), cam.dir(i + 0.5, j + 0.5));
        ASSERT_GT(want, 0.0);
        EXPECT_NEAR(acc[j][i], want, 1e-4) << "view " << k << " pixel " << i << "," << j;
      }
  }
  // Views aimed at the furniture and the ball, so that every kind of surface is checked.
  int seen[3] = {0, 0, 0};
  for (const auto& [at, eye] : std::vector<std::pair<V3, V3>>{{{-0.8, 1.35, 0.5}, {0.0, -0.2, 1.5}},
                                                              {{2.2, -1.7, 0.9}, {0.3, 0.2, 1.4}},
                                                              {{1.15, 0.95, 0.35}, {0.2, -0.3, 1.3}},
                                                              {{-2.2, -0.8, 0.3}, {-0.3, 0.3, 1.6}}}) {
    const V3 f = sub(at, eye);
    const double yaw = std::atan2(f[1], f[0]), pitch = std::atan2(f[2], std::hypot(f[0], f[1]));
    const synth::Camera c = synth::look_along({eye[0], eye[1], eye[2]}, yaw, pitch, kRes);
    const synth::ViewImage img = synth::render_view(c, 1, false, {1, 1, 1}, nullptr, synth::room_tracer());
    const JsonCamera cam = camera_from_synth(c);
    for (int j = 0; j < kRes; ++j)
      for (int i = 0; i < kRes; ++i) {
        int which = -1;
        const double want = first_surface(room, cam.origin(), cam.dir(i + 0.5, j + 0.5), &which);
        ASSERT_GT(want, 0.0);
        EXPECT_NEAR(img.depth[static_cast<size_t>(j * kRes + i)], want, 1e-4) << "aimed view, pixel " << i << "," << j;
        ++seen[which];
      }
  }
  EXPECT_GT(seen[0], 500);  // walls, floor, ceiling
  EXPECT_GT(seen[1], 200);  // furniture
  EXPECT_GT(seen[2], 40);   // the ball
}

TEST_F(SynthRoom, CamerasStandInsideAwayFromTheFurnitureAndLookOutward) {
  const RoomRef room = room_from_scene_json(dir());
  // The written ones are the drawn ones.
  const json tj = read_json(dir() + "/transforms.json");
  const auto train = synth::room_train_cameras(kTrain, kRes, kSeed),
             test = synth::room_test_cameras(kTest, kRes, kSeed);
  for (int k = 0; k < kTrain + kTest; ++k) {
    const synth::Camera& c = k < kTrain ? train[static_cast<size_t>(k)] : test[static_cast<size_t>(k - kTrain)];
    const auto& m = tj.at("frames").at(static_cast<size_t>(k)).at("transform_matrix");
    for (int r = 0; r < 3; ++r)
      for (int col = 0; col < 4; ++col) EXPECT_DOUBLE_EQ(m.at(r).at(col).get<double>(), c.c2w[r][col]);
  }
  // A phone's field of view.
  const double fov_deg = 2.0 * std::atan(0.5 * kRes / tj.at("fl_x").get<double>()) * 180.0 / M_PI;
  EXPECT_GE(fov_deg, 60.0);
  EXPECT_LE(fov_deg, 70.0);
  // Many draws: the stated ranges hold for each, and are covered.
  for (const uint64_t seed : {0ULL, 11ULL}) {
    std::vector<synth::Camera> cams = synth::room_train_cameras(300, 8, seed);
    for (const auto& c : synth::room_test_cameras(300, 8, seed)) cams.push_back(c);
    double pitch_lo = 90, pitch_hi = -90, r_lo = 1, r_hi = 0;
    int yaw_quadrant[4] = {0, 0, 0, 0}, pos_quadrant[4] = {0, 0, 0, 0};
    for (const auto& c : cams) {
      const V3 o{c.c2w[0][3], c.c2w[1][3], c.c2w[2][3]};
      const V3 right{c.c2w[0][0], c.c2w[1][0], c.c2w[2][0]}, up{c.c2w[0][1], c.c2w[1][1], c.c2w[2][1]};
      const V3 fwd{-c.c2w[0][2], -c.c2w[1][2], -c.c2w[2][2]};
      // A rotation (right-handed, orthonormal) with no roll: right is horizontal, up points up.
      EXPECT_NEAR(dot3(right, right), 1.0, 1e-12);
      EXPECT_NEAR(dot3(up, up), 1.0, 1e-12);
      EXPECT_NEAR(dot3(fwd, fwd), 1.0, 1e-12);
      EXPECT_NEAR(dot3(right, up), 0.0, 1e-12);
      EXPECT_NEAR(dot3(right, fwd), 0.0, 1e-12);
      EXPECT_NEAR(dot3(up, fwd), 0.0, 1e-12);
      EXPECT_NEAR(right[2], 0.0, 1e-12);
      EXPECT_GT(up[2], 0.0);
      // (right x up) = backwards = -forward.
      EXPECT_NEAR(right[1] * up[2] - right[2] * up[1], -fwd[0], 1e-12);
      // Position: in the disc of radius 0.6 at heights 1.2-1.7, strictly inside the room, clear of
      // the furniture by more than 0.3.
      const double r = std::hypot(o[0], o[1]);
      EXPECT_LE(r, 0.6 + 1e-12);
      EXPECT_GE(o[2], 1.2);
      EXPECT_LE(o[2], 1.7);
      for (int a = 0; a < 3; ++a) {
        EXPECT_GT(o[a], room.lo[a] + 0.5);
        EXPECT_LT(o[a], room.hi[a] - 0.5);
      }
      for (const auto& [lo, hi] : room.boxes) {
        double d2 = 0;
        for (int a = 0; a < 3; ++a) {
          const double gap = std::max({lo[a] - o[a], 0.0, o[a] - hi[a]});
          d2 += gap * gap;
        }
        EXPECT_GT(std::sqrt(d2), 0.3);
      }
      for (const auto& [centre, radius] : room.spheres)
        EXPECT_GT(std::sqrt(dot3(sub(o, centre), sub(o, centre))), radius + 0.3);
      // Direction: pitch in [-20, 10] degrees; looking outward, away from the disc's centre.
      const double pitch = std::asin(fwd[2]) * 180.0 / M_PI;
      EXPECT_GE(pitch, -20.0 - 1e-9);
      EXPECT_LE(pitch, 10.0 + 1e-9);
      EXPECT_GE(o[0] * fwd[0] + o[1] * fwd[1], 0.0);
      pitch_lo = std::min(pitch_lo, pitch);
      pitch_hi = std::max(pitch_hi, pitch);
      r_lo = std::min(r_lo, r);
      r_hi = std::max(r_hi, r);
      ++yaw_quadrant[(fwd[0] > 0) + 2 * (fwd[1] > 0)];
      ++pos_quadrant[(o[0] > 0) + 2 * (o[1] > 0)];
    }
    EXPECT_LT(pitch_lo, -17.0);
    EXPECT_GT(pitch_hi, 7.0);
    EXPECT_LT(r_lo, 0.1);
    EXPECT_GT(r_hi, 0.55);
    for (int q = 0; q < 4; ++q) {
      EXPECT_GT(yaw_quadrant[q], 100) << "yaw quadrant " << q;  // of 600: about 150 each
      EXPECT_GT(pos_quadrant[q], 100) << "position quadrant " << q;
    }
  }
  // The seed moves the cameras; the test views are a stream apart from the train views.
  const auto a = synth::room_train_cameras(3, 8, 1), b = synth::room_train_cameras(3, 8, 2);
  const auto t = synth::room_test_cameras(3, 8, 1);
  EXPECT_NE(a[0].c2w[0][3], b[0].c2w[0][3]);
  EXPECT_NE(a[0].c2w[0][3], t[0].c2w[0][3]);
}

TEST_F(SynthRoom, EveryPixelIsOpaqueAndSeesASurface) {
  for (const auto& [split, n] : {std::pair<std::string, int>{"train", kTrain}, {"test", kTest}})
    for (int k = 0; k < n; ++k) {
      const std::string base = dir() + "/" + split + "/r_" + std::to_string(k);
      const auto im = read_png(base + ".png");  // (H, W, C) uint8
      ASSERT_EQ(im.sizes(), (std::vector<int64_t>{kRes, kRes, 4}));
      EXPECT_EQ(im.select(2, 3).min().item<int>(), 255) << base;
      // The darkest a surface gets is albedo 0.05 in ambient light 0.2: linear 0.01, sRGB 25/255.
      // A transparent or empty pixel would be black.
      EXPECT_GE(im.slice(2, 0, 3).min().item<int>(), 20) << base;
      if (split == "test") {
        EXPECT_GT(load_depth(base + "_depth.pt").min().item<float>(), 0.1f) << base;
      }
    }
  // The renderer's own output: alpha exactly 1 on every pixel.
  const synth::Camera c = synth::room_test_cameras(1, 12, 9)[0];
  const synth::ViewImage img = synth::render_view(c, 1, false, {1, 1, 1}, nullptr, synth::room_tracer());
  for (size_t p = 0; p < img.depth.size(); ++p) EXPECT_EQ(img.rgba[p * 4 + 3], 1.0f);
}

TEST_F(SynthRoom, LoadsAsARealCaptureAndTheLoadersRaysAreTheRenderers) {
  const json scene = read_json(dir() + "/scene.json");
  EXPECT_EQ(scene.at("layout"), "nerfstudio");
  const json tj = read_json(dir() + "/transforms.json");
  EXPECT_EQ(tj.at("camera_model"), "PINHOLE");
  EXPECT_EQ(tj.at("train_filenames").size(), static_cast<size_t>(kTrain));
  EXPECT_EQ(tj.at("test_filenames").size(), static_cast<size_t>(kTest));
  const Capture capture = read_capture(dir(), {}, 1);
  EXPECT_EQ(capture.format, "nerfstudio");
  EXPECT_FALSE(capture.synthetic);  // a real capture, not a Blender object scene
  const Dataset ds = Dataset::load(dir());
  EXPECT_EQ(ds.format, "nerfstudio");
  ASSERT_EQ(ds.split("train").size(), kTrain);
  ASSERT_EQ(ds.split("test").size(), kTest);
  EXPECT_EQ(ds.intrinsics.width, kRes);
  EXPECT_NEAR(ds.intrinsics.fx, synth::focal_from_angle(kRes, synth::kRoomCameraAngleX), 1e-9);
  const RayMismatch worst = loader_ray_mismatch(ds, synth::room_train_cameras(kTrain, kRes, kSeed),
                                                {{0, 0}, {31, 0}, {0, 31}, {31, 31}, {15, 16}});
  EXPECT_LT(worst.direction, 2e-6);  // poses are stored in float32
  EXPECT_LT(worst.origin, 2e-6);
  // Opaque photos load unchanged by the white background; depth in scene units.
  EXPECT_EQ(ds.split("train").alpha.min().item<float>(), 1.0f);
  ASSERT_TRUE(ds.split("test").depth.defined());
  const auto raw = load_depth(dir() + "/test/r_0_depth.pt");
  EXPECT_TRUE(torch::allclose(ds.split("test").depth[0], raw * ds.scene.scale, 1e-5, 1e-6));
}

// The room comes with sparse points (nerfstudio's ply_file_path), as a capture processed by SfM
// does: each on a surface (inside the room's box, on one of its faces or within a furniture
// object's reach of one), and they give the scene frame its bounds and, the cameras looking out,
// its scale (data/scene_frame.h).
TEST_F(SynthRoom, SparsePointsLieOnTheRoomsSurfacesAndFitTheFrame) {
  const json tj = read_json(dir() + "/transforms.json");
  ASSERT_EQ(tj.at("ply_file_path"), "sparse_pc.ply");
  const Capture capture = read_capture(dir(), {}, 1);
  ASSERT_GE(capture.points.size(), 8u);
  size_t on_face = 0;
  for (const auto& p : capture.points) {
    const double q[3] = {p[0], p[1], p[2]};
    const double lo[3] = {synth::kRoomMin.x, synth::kRoomMin.y, synth::kRoomMin.z};
    const double hi[3] = {synth::kRoomMax.x, synth::kRoomMax.y, synth::kRoomMax.z};
    bool face = false;
    for (int k = 0; k < 3; ++k) {
      EXPECT_GE(q[k], lo[k] - 1e-6);
      EXPECT_LE(q[k], hi[k] + 1e-6);
      face = face || std::abs(q[k] - lo[k]) < 1e-6 || std::abs(q[k] - hi[k]) < 1e-6;
    }
    on_face += face;
  }
  // The cameras look out at the walls: most points are on the room's faces.
  EXPECT_GT(on_face, capture.points.size() / 2);
  const Dataset ds = Dataset::load(dir());
  EXPECT_EQ(ds.scene.bounds_source, "points");
  EXPECT_TRUE(ds.scene.looks_outward);
  // The unit sphere holds half the points: the scene is larger than the cameras' sphere.
  EXPECT_LT(ds.split("train").c2w.select(2, 3).norm(2, 1).max().item<double>(), 0.6);
}

TEST(SynthRoomShading, LambertWithInverseSquareFalloffAndHardShadows) {
  // Floor points: one in the ball's shadow from the ceiling lamp (on the line from the lamp
  // through the ball's centre), one in the open. Expected radiance from the closed form, with
  // visibility decided here by sampling the segment to each light against the ball and the boxes
  // (independent of the tracer's slab and quadratic solutions).
  const auto& lights = synth::room_lights();
  const synth::Sphere& ball = synth::room_ball();
  const Vec3 lamp = lights.at(0).position;
  const Vec3 to_ball = ball.centre - lamp;
  const Vec3 in_shadow = lamp + to_ball * (lamp.z / -to_ball.z);  // where that line meets z = 0
  const Vec3 in_open{-0.3, -1.2, 0.0};
  const double min_d2 = synth::kRoomLightMinDistance * synth::kRoomLightMinDistance;
  for (const Vec3& p : {in_shadow, in_open}) {
    Vec3 irradiance = synth::room_ambient();
    for (size_t k = 0; k < lights.size(); ++k) {
      const Vec3 L = lights[k].position - p;
      const double d2 = dot(L, L), cos_l = L.z / std::sqrt(d2);  // the floor's normal is +z
      const Vec3 term = lights[k].intensity * (cos_l / std::max(d2, min_d2));
      bool blocked = false;
      for (int s = 1; s < 4000 && !blocked; ++s) {
        const Vec3 q = p + L * (s / 4000.0);
        if (length(q - ball.centre) < ball.radius) blocked = true;
        for (const auto& b : synth::room_furniture())
          if (q.x > b.lo.x && q.x < b.hi.x && q.y > b.lo.y && q.y < b.hi.y && q.z > b.lo.z && q.z < b.hi.z)
            blocked = true;
      }
      if (k == 0) {
        EXPECT_EQ(blocked, p == in_shadow);  // the lamp: hidden by the ball, or seen
        EXPECT_GT(term.x, 0.2);              // and its light matters there
      }
      if (!blocked && cos_l > 0) irradiance += term;
    }
    const Vec3 want = synth::room_albedo(0, p) * irradiance;
    // Seen from above and to the side (clear of the ball), straight at p.
    const Vec3 eye = p + Vec3{0.5, 0.6, 1.0};
    const synth::Ray r{eye, p - eye};
    const synth::Hit h = synth::intersect_room(r);
    ASSERT_EQ(h.object, 0);  // the floor
    ASSERT_NEAR(h.t, 1.0, 1e-12);
    const Vec3 got = synth::trace_room(r);
    EXPECT_NEAR(got.x, want.x, 1e-9);
    EXPECT_NEAR(got.y, want.y, 1e-9);
    EXPECT_NEAR(got.z, want.z, 1e-9);
  }
  // Every albedo lies in [0.05, 0.9]: points spread through the room, for every object.
  const Vec3 lo = synth::kRoomMin, hi = synth::kRoomMax;
  for (int object = 0; object < synth::room_object_count(); ++object)
    for (int k = 0; k < 2000; ++k) {
      const double u = (k % 50) / 50.0, v = (k / 50) / 40.0;
      const Vec3 p{lo.x + (hi.x - lo.x) * u, lo.y + (hi.y - lo.y) * v, lo.z + (hi.z - lo.z) * u * v};
      const Vec3 a = synth::room_albedo(object, p);
      for (size_t c = 0; c < 3; ++c) {
        EXPECT_GE(a[c], synth::kRoomAlbedoMin);
        EXPECT_LE(a[c], synth::kRoomAlbedoMax);
      }
    }
}

TEST(SynthRoomDeterminism, SameSeedIsByteIdenticalWhateverTheThreadsAndSeedsDiffer) {
  test::TempDir a("room_a"), b("room_b"), c("room_c");
  SynthOptions o = room_options(12, 2, 1, 3);
  o.threads = 1;
  write_synthetic_dataset(a.path(), o);
  o.threads = 3;
  write_synthetic_dataset(b.path(), o);
  o.seed = 4;
  write_synthetic_dataset(c.path(), o);
  const std::vector<std::string> files = {"transforms.json", "scene.json",        "train/r_0.png",     "train/r_1.png",
                                          "test/r_0.png",    "test/r_0_depth.pt", "test/r_0_depth.png"};
  for (const auto& f : files) EXPECT_EQ(read_file(a / f), read_file(b / f)) << f;
  // Another seed moves every camera, the test views' too.
  for (const char* f : {"transforms.json", "train/r_0.png", "train/r_1.png", "test/r_0.png", "test/r_0_depth.pt"})
    EXPECT_NE(read_file(a / f), read_file(c / f)) << f;
}

TEST(SynthRoomVariants, LensAndPoseNoiseWorkAndRefusalsNameTheFlag) {
  test::TempDir t("room_variants");
  SynthOptions o = room_options(12, 3, 1, 2);
  o.lens = "opencv";
  o.exposure_jitter = 0.5;
  o.pose_noise_deg = 1.0;
  o.pose_noise_shift = 0.02;
  write_synthetic_dataset(t.path(), o);
  const json tj = read_json(t / "transforms.json");
  EXPECT_EQ(tj.at("camera_model"), "OPENCV");
  const json scene = read_json(t / "scene.json");
  ASSERT_EQ(scene.at("train_view_truth").size(), 3u);
  const RoomRef room = room_from_scene_json(t.path());
  for (size_t k = 0; k < 3; ++k) {
    EXPECT_EQ(read_png(t / ("train/r_" + std::to_string(k) + ".png")).select(2, 3).min().item<int>(), 255);
    // The shift is 2% of the true camera's distance to what it looks at (along its optical axis).
    const auto& tm = scene.at("train_view_truth")[k].at("true_transform_matrix");
    const V3 o_true{tm[0][3].get<double>(), tm[1][3].get<double>(), tm[2][3].get<double>()};
    const V3 axis{-tm[0][2].get<double>(), -tm[1][2].get<double>(), -tm[2][2].get<double>()};
    const auto& wm = tj.at("frames")[k].at("transform_matrix");
    const V3 o_noisy{wm[0][3].get<double>(), wm[1][3].get<double>(), wm[2][3].get<double>()};
    const V3 shift = sub(o_noisy, o_true);
    EXPECT_NEAR(std::sqrt(dot3(shift, shift)), 0.02 * first_surface(room, o_true, axis), 1e-9);
  }
  // Refusals.
  SynthOptions bad = room_options(16, 2, 1, 0);
  EXPECT_EQ(bad.resolved_layout(), "nerfstudio");
  bad.scene = "kitchen";
  test::expect_input_error([&] { synth::validate(bad); }, "synth", "--scene", "demo or room", true);
  bad = room_options(16, 2, 1, 0);
  bad.background = "environment";
  test::expect_input_error([&] { synth::validate(bad); }, "synth", "--background", "closed", true);
  bad = room_options(16, 2, 1, 0);
  bad.distractor = true;
  test::expect_input_error([&] { synth::validate(bad); }, "synth", "--distractor", "demo", true);
  bad = room_options(16, 2, 1, 0);
  bad.layout = "blender";
  test::expect_input_error([&] { synth::validate(bad); }, "synth", "--layout", "real capture", true);
  // The demo scene stays the default.
  EXPECT_EQ(SynthOptions{}.scene, "demo");
  EXPECT_EQ(SynthOptions{}.resolved_layout(), "blender");
}

}  // namespace room_test
