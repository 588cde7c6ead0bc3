// Camera refinement end to end (model/camera_refine.h): `synth` perturbs the training cameras by a
// known amount (2 degrees about a random axis, a shift of 2% of the distance) and records the truth;
// the demo preset with train.camera_refine learns the scene and the corrections; `export --cameras`
// writes the refined cameras; their reprojection error on the objects against the truth must be
// under half of the perturbed cameras'. Measured with these settings (1500 steps of 128 rays,
// 2026-12-03, 2-core machine): 1.57 degrees perturbed, 0.35 refined (0.22 of it); after aligning each
// set of cameras to the truth (`metrics --cameras`), 0.19 of it, as with 256 rays a step (0.24 and
// 0.19 there, 2026-11-27), in 60% of the time.
// Held-out cameras turned by 2 degrees are found again by `eval --align-cameras`. Without refinement
// the export is refused with one line.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "test_util.h"
#include "util/fs.h"

namespace ablenerf {
namespace {

using json = nlohmann::json;
using Pose = std::array<std::array<double, 4>, 3>;

Pose pose_of(const json& m) {
  Pose p{};
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) p[r][c] = m.at(r).at(c).get<double>();
  return p;
}

// Mean angle (degrees) between the directions in which cameras a and b see the points of a 3x3x3
// lattice spanning the demo scene's objects (|x|, |y|, |z| <= 0.8).
double reprojection_deg(const Pose& a, const Pose& b) {
  double sum = 0;
  int n = 0;
  for (double x : {-0.8, 0.0, 0.8})
    for (double y : {-0.8, 0.0, 0.8})
      for (double z : {-0.8, 0.0, 0.8}) {
        const double p[3] = {x, y, z};
        double da[3], db[3], na = 0, nb = 0, dot = 0;
        for (int k = 0; k < 3; ++k) {
          da[k] = db[k] = 0;
          for (int r = 0; r < 3; ++r) {
            da[k] += a[r][k] * (p[r] - a[r][3]);  // R^T (p - c): the camera-frame direction
            db[k] += b[r][k] * (p[r] - b[r][3]);
          }
          na += da[k] * da[k];
          nb += db[k] * db[k];
        }
        for (int k = 0; k < 3; ++k) dot += da[k] * db[k];
        sum += std::acos(std::min(1.0, dot / std::sqrt(na * nb))) * 180.0 / M_PI;
        ++n;
      }
  return sum / n;
}

TEST(CameraRefineCli, RefinedCamerasReprojectWithinHalfThePerturbedError) {
  test::TempDir t;
  auto r =
      test::run_cli("synth --out " + (t / "data") +
                    " --res 32 --train-views 24 --test-views 2 --pose-noise-deg 2 --pose-noise-shift 0.02 --seed 0");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const std::string common = " --data " + (t / "data") + " --config " + test::source_dir() +
                             "/configs/demo.toml --set train.steps=1500 --set train.time_budget_s=0"
                             " --set train.rays_per_step=128 --set train.micro_batch=128 --set train.eval_every=0"
                             " --set train.ckpt_every=0 --quiet";
  r = test::run_cli("train" + common + " --set train.camera_refine=true --out " + (t / "run"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = test::run_cli("export --run " + (t / "run") + " --cameras " + (t / "poses.json"));
  ASSERT_EQ(r.exit_code, 0) << r.output;

  const json truth = json::parse(read_file(t / "data/scene.json")).at("train_view_truth");
  const json given = json::parse(read_file(t / "data/transforms_train.json")).at("frames");
  const json refined = json::parse(read_file(t / "poses.json")).at("frames");
  ASSERT_EQ(truth.size(), 24u);
  ASSERT_EQ(refined.size(), 24u);
  double before = 0, after = 0;
  for (size_t i = 0; i < truth.size(); ++i) {
    const Pose want = pose_of(truth[i].at("true_transform_matrix"));
    before += reprojection_deg(pose_of(given[i].at("transform_matrix")), want) / 24;
    after += reprojection_deg(pose_of(refined[i].at("transform_matrix")), want) / 24;
    EXPECT_GT(refined[i].at("refined_rotation_deg").get<double>(), 0.0);
  }
  EXPECT_GT(before, 1.0);  // the perturbation is there
  std::cout << "perturbed " << before << " deg, refined " << after << " deg" << std::endl;
  EXPECT_LT(after, 0.5 * before) << "perturbed " << before << " deg, refined " << after << " deg";
  // `metrics --cameras` after aligning each rig to the truth (BARF's protocol: the motion common to all
  // cameras is one no photo reveals): measured 0.19 of the given poses' error, under the fifth the
  // refinement is asked for; the same at 48 and 64 pixels (0.185, 0.189) and after twice the steps
  // (0.191), so a floor of this scene and perturbation, not of training time (docs/benchmarks/history.md,
  // "Camera refinement's floor"). Another CPU's rounding moves it: 0.223 on an AMD EPYC (Zen 4) with
  // the same binary and seed. The bound, a quarter, leaves room for that; unrefined cameras score 1.
  // At 800 steps of 256 rays the ratio was 0.225: the steps, not the rays, reach the floor.
  const auto aligned_error = [&](const std::string& file) {
    const auto m = test::run_cli("metrics --cameras " + file + " --truth " + (t / "data"));
    EXPECT_EQ(m.exit_code, 0) << m.output;
    return json::parse(m.output).at("aligned").at("reprojection_deg").get<double>();
  };
  const double given_aligned = aligned_error(t / "data/transforms_train.json");
  const double refined_aligned = aligned_error(t / "poses.json");
  std::cout << "aligned: given " << given_aligned << ", refined " << refined_aligned << std::endl;
  EXPECT_LT(refined_aligned, 0.25 * given_aligned) << "given " << given_aligned << ", refined " << refined_aligned;

  // Held-out cameras aligned before scoring: a copy of the capture whose test cameras are turned by
  // 2 degrees scores far below the capture as it is in the plain protocol, and back within 1 dB of
  // it with --align-cameras (metrics.json names the protocol and each view's correction).
  std::filesystem::copy(t / "data", t / "turned", std::filesystem::copy_options::recursive);
  json test_frames = json::parse(read_file(t / "data/transforms_test.json"));
  const double a = 2.0 * M_PI / 180.0;
  const double turn[3][3] = {{std::cos(a), 0, std::sin(a)}, {0, 1, 0}, {-std::sin(a), 0, std::cos(a)}};
  for (auto& f : test_frames.at("frames")) {
    const Pose p = pose_of(f.at("transform_matrix"));
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c)
        f["transform_matrix"][r][c] = turn[r][0] * p[0][c] + turn[r][1] * p[1][c] + turn[r][2] * p[2][c];
  }
  test::write_file(t / "turned/transforms_test.json", test_frames.dump(2));
  const auto psnr_of = [&](const std::string& args) {
    const auto e = test::run_cli("eval --run " + (t / "run") + " " + args);
    EXPECT_EQ(e.exit_code, 0) << e.output;
    return json::parse(read_file(t / "run/eval/test/metrics.json"));
  };
  const json as_is = psnr_of("--data " + (t / "data"));
  const json turned = psnr_of("--data " + (t / "turned"));
  const json aligned = psnr_of("--data " + (t / "turned") + " --align-cameras");
  EXPECT_EQ(as_is.at("protocol"), "plain");
  EXPECT_EQ(aligned.at("protocol"), "aligned cameras");
  const double p0 = as_is["mean"]["psnr"].get<double>(), p1 = turned["mean"]["psnr"].get<double>(),
               p2 = aligned["mean"]["psnr"].get<double>();
  std::cout << "psnr as is " << p0 << ", turned " << p1 << ", aligned " << p2 << std::endl;
  EXPECT_LT(p1, p0 - 3.0) << "as is " << p0 << ", turned " << p1;
  EXPECT_GT(p2, p0 - 1.0) << "as is " << p0 << ", turned and aligned " << p2;
  // Each view's correction: found on every view, about the 2 degrees on average. At 32 pixels the
  // fit falls short of the turn and scatters with the model's rounding: 0.87-1.51 degrees per view
  // over two training seeds and two builds (2026-12-04), so one view is held to [0.5, 3.5] and the
  // views' mean to 2 +- 1.
  double mean_rotation = 0;
  for (const auto& im : aligned.at("images")) {
    const double deg = im.at("aligned_rotation_deg").get<double>();
    EXPECT_GT(deg, 0.5);
    EXPECT_LT(deg, 3.5);
    mean_rotation += deg / static_cast<double>(aligned.at("images").size());
  }
  EXPECT_NEAR(mean_rotation, 2.0, 1.0);

  // A run that did not refine its cameras: one line naming the weights' field, exit code 2.
  r = test::run_cli("train" + common + " --set train.steps=5 --out " + (t / "plain"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = test::run_cli("export --run " + (t / "plain") + " --cameras " + (t / "none.json"));
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("camera_refine.correction"), std::string::npos) << r.output;
  EXPECT_FALSE(std::filesystem::exists(t / "none.json"));
}

// The focal length refined (train.camera_refine_focal): the capture's cameras, train and test alike,
// are given a focal length 5% too long (camera_angle_x narrowed), as when structure from motion
// misjudges the one camera of a capture; training with the focal scale moves k toward 1 / 1.05, and
// eval, which renders the held-out photos with k times their given focal length, and `export
// --cameras` report it. This capture hardly fixes the focal length (cameras 4 units from objects within
// 0.8 of the origin, 32 pixels: a scene scaled by k images the same to a third of a pixel), so the
// test asks only that the error shrink, to under 0.8 of the given: measured 0.62 (k 0.982 against the
// true 0.952, 2026-11-28); at the run's full learning rate k overshot to 0.894 (error 1.22 of the
// given), which this bound refuses.
TEST(CameraRefineCli, RefinedFocalLengthFindsTheCapturesCamera) {
  test::TempDir t;
  auto r = test::run_cli("synth --out " + (t / "data") + " --res 32 --train-views 24 --test-views 2 --seed 0");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const double given_over_true = 1.05;
  for (const std::string split : {"train", "test"}) {
    json j = json::parse(read_file(t / ("data/transforms_" + split + ".json")));
    const double angle = j.at("camera_angle_x").get<double>();
    j["camera_angle_x"] = 2 * std::atan(std::tan(angle / 2) / given_over_true);  // focal x 1.05
    test::write_file(t / ("data/transforms_" + split + ".json"), j.dump(2));
  }
  r = test::run_cli("train --data " + (t / "data") + " --config " + test::source_dir() +
                    "/configs/demo.toml --set train.steps=1500 --set train.time_budget_s=0 --set train.eval_every=0"
                    " --set train.ckpt_every=0 --quiet --set train.camera_refine=true"
                    " --set train.camera_refine_focal=true --out " +
                    (t / "run"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = test::run_cli("eval --run " + (t / "run"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const json m = json::parse(read_file(t / "run/eval/test/metrics.json"));
  const double k = m.at("refined_focal_scale").get<double>();
  std::cout << "focal scale " << k << ", error " << std::abs(k * given_over_true - 1.0) / (given_over_true - 1.0)
            << " of the given" << std::endl;
  EXPECT_LT(std::abs(k * given_over_true - 1.0), 0.8 * (given_over_true - 1.0)) << "focal scale " << k;
  EXPECT_LT(k, 1.0);  // toward the truth
  // `export --cameras` writes the refined focal length.
  r = test::run_cli("export --run " + (t / "run") + " --cameras " + (t / "poses.json"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const json poses = json::parse(read_file(t / "poses.json"));
  const json given = json::parse(read_file(t / "data/transforms_train.json"));
  const double given_fx = 16.0 / std::tan(given.at("camera_angle_x").get<double>() / 2);  // 32 pixels wide
  EXPECT_NEAR(poses.at("refined_focal_scale").get<double>(), k, 1e-6);
  EXPECT_NEAR(poses.at("frames").at(0).at("fl_x").get<double>(), k * given_fx, 1e-3 * given_fx);
  // Focal refinement alone is refused with one line naming the key.
  r = test::run_cli("train --data " + (t / "data") + " --config " + test::source_dir() +
                    "/configs/demo.toml --set train.camera_refine_focal=true --set train.steps=5 --out " +
                    (t / "alone"));
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("camera_refine_focal"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace ablenerf
