// The demo scene's capture variants (`synth --lens opencv`, `--background environment`): the lens's
// fixed-point inverse, the loader's rays against the renderer's own rays through the lens (two
// independent inverses: Newton in src/data, fixed point in src/synth), depth in scene units, the
// opaque environment background, the nerfstudio layout and the option checks.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "data/dataset.h"
#include "synth/scene.h"
#include "synth/world.h"
#include "loader_rays.h"
#include "test_util.h"
#include "util/errors.h"
#include "util/fs.h"
#include "util/image_io.h"
#include "data/data_config.h"

using namespace ablenerf;
using nlohmann::json;

namespace {

SynthOptions variant(int res, const std::string& lens, const std::string& background) {
  SynthOptions o;
  o.res = res;
  o.train_views = 5;
  o.test_views = 2;
  o.threads = 1;
  o.lens = lens;
  o.background = background;
  return o;
}

}  // namespace

TEST(SynthLens, FixedPointInverseRoundTripsOverTheImage) {
  // Normalised coordinates of a square view with Blender's field of view, corners included.
  const double half = std::tan(0.5 * synth::kCameraAngleX);
  double worst = 0;
  for (int i = 0; i <= 20; ++i)
    for (int j = 0; j <= 20; ++j) {
      const double x = half * (i / 10.0 - 1), y = half * (j / 10.0 - 1);
      double xd, yd, ux, uy;
      synth::distort_point(synth::kWideLens, x, y, xd, yd);
      synth::undistort_point(synth::kWideLens, xd, yd, ux, uy);
      worst = std::max({worst, std::abs(ux - x), std::abs(uy - y)});
    }
  EXPECT_LT(worst, 1e-12);
  // The lens is strong enough to matter: a corner moves inwards by more than 5% of its radius.
  double xd, yd;
  synth::distort_point(synth::kWideLens, half, half, xd, yd);
  EXPECT_LT(std::hypot(xd, yd), 0.95 * std::hypot(half, half));
}

TEST(SynthVariants, LoaderRaysThroughTheLensAreTheRenderersRays) {
  test::TempDir t;
  const SynthOptions o = variant(24, "opencv", "transparent");
  write_synthetic_dataset(t.path(), o);
  const json tj = json::parse(read_file(t / "transforms.json"));
  EXPECT_EQ(tj.at("camera_model"), "OPENCV");
  EXPECT_DOUBLE_EQ(tj.at("k1").get<double>(), synth::kWideLens.k1);
  LoadOptions lo;
  lo.scene = SceneKind::Bounded;
  const Dataset ds = Dataset::load(t.path(), lo);
  EXPECT_EQ(ds.format, "nerfstudio");
  ASSERT_EQ(ds.split("train").size(), o.train_views);
  ASSERT_EQ(ds.split("test").size(), o.test_views);
  EXPECT_EQ(ds.intrinsics.model, LensModel::RadialTangential);
  auto cams = synth::train_cameras(o.train_views, o.res, o.seed);
  for (auto& cam : cams) cam.lens = synth::kWideLens;
  const synth_test::RayMismatch worst =
      synth_test::loader_ray_mismatch(ds, cams, {{0, 0}, {23, 0}, {0, 23}, {23, 23}, {11, 12}, {5, 17}});
  EXPECT_LT(worst.direction, 2e-6);  // poses are stored in float32
  EXPECT_LT(worst.origin, 2e-6);
  // Depth maps are in scene units: the renderer's depth times the scene frame's scale.
  const auto raw = torch::pickle_load([&] {
                     const std::string b = read_file(t / "test/r_0_depth.pt");
                     return std::vector<char>(b.begin(), b.end());
                   }())
                       .toTensor();
  ASSERT_TRUE(ds.split("test").depth.defined());
  EXPECT_TRUE(torch::allclose(ds.split("test").depth[0], raw * ds.scene.scale, 1e-5, 1e-6));
  EXPECT_GT(raw.max().item<double>(), 1.0);  // the check is not vacuous
}

TEST(SynthVariants, EnvironmentBackgroundIsOpaqueAndShowsTheSky) {
  test::TempDir t;
  write_synthetic_dataset(t.path(), variant(16, "pinhole", "environment"));
  const json tj = json::parse(read_file(t / "transforms.json"));
  EXPECT_EQ(tj.at("camera_model"), "PINHOLE");
  EXPECT_FALSE(tj.contains("k1"));
  const json scene = json::parse(read_file(t / "scene.json"));
  EXPECT_EQ(scene.at("layout"), "nerfstudio");
  const auto img = read_png(t / "test/r_0.png");  // (H, W, 4) uint8
  EXPECT_EQ(img.select(2, 3).min().item<int>(), 255);
  // The top-left pixel misses every object: its colour is the environment along its 3x3
  // sub-sample rays, averaged in linear light.
  const synth::Camera cam = synth::test_cameras(2, 16)[0];
  Vec3 sum;
  for (int sy = 0; sy < synth::kSubsamplesPerAxis; ++sy)
    for (int sx = 0; sx < synth::kSubsamplesPerAxis; ++sx) {
      const synth::Ray r =
          synth::camera_ray(cam, (sx + 0.5) / synth::kSubsamplesPerAxis, (sy + 0.5) / synth::kSubsamplesPerAxis);
      ASSERT_FALSE(synth::intersect_scene(r).hit());
      const Vec3 e = synth::environment(normalize(r.dir));
      sum += Vec3{std::clamp(e.x, 0.0, 1.0), std::clamp(e.y, 0.0, 1.0), std::clamp(e.z, 0.0, 1.0)};
    }
  const double n = synth::kSubsamplesPerAxis * synth::kSubsamplesPerAxis;
  EXPECT_NEAR(img[0][0][0].item<int>() / 255.0, synth::linear_to_srgb(sum.x / n), 0.6 / 255);
  EXPECT_NEAR(img[0][0][1].item<int>() / 255.0, synth::linear_to_srgb(sum.y / n), 0.6 / 255);
  EXPECT_NEAR(img[0][0][2].item<int>() / 255.0, synth::linear_to_srgb(sum.z / n), 0.6 / 255);
  // The default stays the transparent Blender layout.
  test::TempDir b;
  write_synthetic_dataset(b.path(), variant(16, "pinhole", "transparent"));
  EXPECT_TRUE(std::filesystem::exists(b / "transforms_train.json"));
  EXPECT_EQ(read_png(b / "test/r_0.png")[0][0][3].item<int>(), 0);
}

TEST(SynthVariants, OptionChecks) {
  SynthOptions o = variant(16, "fisheye", "transparent");
  test::expect_input_error([&] { synth::validate(o); }, "synth", "--lens", "", true);
  o = variant(16, "pinhole", "sky");
  test::expect_input_error([&] { synth::validate(o); }, "synth", "--background", "", true);
  o = variant(16, "opencv", "transparent");
  o.layout = "blender";
  test::expect_input_error([&] { synth::validate(o); }, "synth", "--layout", "no lens model", true);
}
