// `ablenerf metrics` through the built CLI ($ABLENERF_BIN): the JSON it prints against the library's
// scores, and one-line errors with exit code 2.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <sstream>
#include <nlohmann/json.hpp>

#include "eval/metrics.h"
#include "test_util.h"
#include "util/image_io.h"

namespace ablenerf {
namespace {

bool cli_available() {
  const char* bin = std::getenv("ABLENERF_BIN");
  return bin && std::filesystem::exists(bin);
}

TEST(MetricsCli, IdenticalImagesScorePerfectly) {
  if (!cli_available()) GTEST_SKIP() << "ABLENERF_BIN not built";
  test::TempDir dir("metrics");
  torch::manual_seed(3);
  write_png(dir / "x.png", torch::rand({40, 36, 3}));
  const std::string pair = "metrics --ref " + (dir / "x.png") + " --img " + (dir / "x.png");
  auto r = test::run_cli(pair + " --ssim release");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  auto j = nlohmann::json::parse(r.output);
  EXPECT_TRUE(j["psnr"].is_null());  // +infinity has no JSON form; explained in psnr_note
  EXPECT_TRUE(j["psnr_note"].is_string());
  EXPECT_EQ(j["mse"].get<double>(), 0.0);
  EXPECT_NEAR(j["ssim"].get<double>(), 1.0, 1e-9);
  EXPECT_EQ(j["ssim_variant"], "release");
  if (j["lpips"].is_null())
    EXPECT_TRUE(j["lpips_note"].is_string());
  else
    EXPECT_NEAR(j["lpips"].get<double>(), 0.0, 1e-6);
}

TEST(MetricsCli, MatchesLibraryOnDifferentImages) {
  if (!cli_available()) GTEST_SKIP() << "ABLENERF_BIN not built";
  test::TempDir dir("metrics");
  torch::manual_seed(4);
  write_png(dir / "a.png", torch::rand({20, 24, 3}));
  write_png(dir / "b.png", torch::rand({20, 24, 3}));
  auto r = test::run_cli("metrics --ref " + (dir / "a.png") + " --img " + (dir / "b.png"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  auto j = nlohmann::json::parse(r.output);
  auto a = read_rgb_for_metrics(dir / "a.png"), b = read_rgb_for_metrics(dir / "b.png");
  EXPECT_NEAR(j["psnr"].get<double>(), psnr(b, a), 1e-9);
  EXPECT_NEAR(j["ssim"].get<double>(), ssim(b, a), 1e-9);
  EXPECT_EQ(j["ssim_variant"], "standard");
  // 20x24 is below AlexNet's minimum input, so LPIPS is reported as skipped.
  EXPECT_TRUE(j["lpips"].is_null());
  EXPECT_TRUE(j["lpips_note"].is_string());
}

TEST(MetricsCli, MismatchedSizesExitTwoNamingBothFiles) {
  if (!cli_available()) GTEST_SKIP() << "ABLENERF_BIN not built";
  test::TempDir dir("metrics");
  write_png(dir / "small.png", torch::zeros({12, 12, 3}));
  write_png(dir / "large.png", torch::zeros({12, 13, 3}));
  auto r = test::run_cli("metrics --ref " + (dir / "small.png") + " --img " + (dir / "large.png"));
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("small.png"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("large.png"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("error:"), std::string::npos) << r.output;
}

TEST(MetricsCli, BadOptionsExitTwo) {
  if (!cli_available()) GTEST_SKIP() << "ABLENERF_BIN not built";
  test::TempDir dir("metrics");
  write_png(dir / "x.png", torch::zeros({40, 40, 3}));
  const std::string pair = "metrics --ref " + (dir / "x.png") + " --img " + (dir / "x.png");
  auto r = test::run_cli(pair + " --ssim skimage");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("skimage"), std::string::npos) << r.output;
  // An explicit but missing LPIPS weights file is an input error naming the file.
  r = test::run_cli(pair + " --lpips-weights " + (dir / "none.pt"));
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("none.pt"), std::string::npos) << r.output;
  r = test::run_cli("metrics --ref " + (dir / "missing.png") + " --img " + (dir / "x.png"));
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("missing.png"), std::string::npos) << r.output;
}

// --geometry against a COLMAP capture: its sparse points' distances to the geometry (a plane's grid
// of points at spacing 0.02 in an ASCII PLY): points over grid nodes at heights 0, 0.02, -0.06, 0.12
// have exactly those distances; a point far beyond the plane is not asked for. A capture with
// neither a scene.json nor sparse points is refused with one line naming scene.json.
TEST(MetricsCli, GeometryAgainstAColmapCapturesSparsePoints) {
  if (!cli_available()) GTEST_SKIP() << "ABLENERF_BIN not built";
  test::TempDir t("metrics");
  std::filesystem::create_directories(t / "cap/sparse/0");
  std::filesystem::create_directories(t / "cap/images");
  test::write_file(t / "cap/sparse/0/cameras.txt", "1 PINHOLE 8 6 10 10 4 3\n");
  test::write_file(t / "cap/sparse/0/images.txt", "1 1 0 0 0 0 0 -3 1 a.png\n\n2 1 0 0 0 0.1 0 -3 1 b.png\n\n");
  test::write_file(t / "cap/sparse/0/points3D.txt",
                   "1 0 0 0 255 0 0 0.5\n2 0.5 -0.24 0.02 255 0 0 0.5\n3 -0.7 0.3 -0.06 255 0 0 0.5\n"
                   "4 0.2 0.9 0.12 255 0 0 0.5\n5 40 0 0 255 0 0 0.5\n");
  write_png(t / "cap/images/a.png", torch::rand({6, 8, 3}));
  write_png(t / "cap/images/b.png", torch::rand({6, 8, 3}));
  std::ostringstream ply;
  ply << "ply\nformat ascii 1.0\nelement vertex " << 101 * 101
      << "\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
  for (int i = -50; i <= 50; ++i)
    for (int k = -50; k <= 50; ++k) ply << 0.02 * i << " " << 0.02 * k << " 0\n";
  test::write_file(t / "plane.ply", ply.str());

  auto r = test::run_cli("metrics --geometry " + t / "plane.ply" + " --truth " + t / "cap" + " --tau 0.05");
  if (r.output.find("no geometry scoring") != std::string::npos) GTEST_SKIP() << "built without Open3D";
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto j = nlohmann::json::parse(r.output);
  EXPECT_EQ(j["reference_points"].get<int64_t>(), 5);
  EXPECT_EQ(j["inside"].get<int64_t>(), 4);
  EXPECT_NEAR(j["distance_mean"].get<double>(), (0.0 + 0.02 + 0.06 + 0.12) / 4, 1e-6);
  EXPECT_DOUBLE_EQ(j["within_tau"].get<double>(), 0.5);
  EXPECT_EQ(j["truth"], "colmap sparse points");

  std::filesystem::remove(t / "cap/sparse/0/points3D.txt");
  r = test::run_cli("metrics --geometry " + t / "plane.ply" + " --truth " + t / "cap");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("scene.json"), std::string::npos) << r.output;
}

// --geometry against a Blender scene's depth maps (data/depth_file.h): one camera 4 units above
// the plane z = 0 looking straight down, its depth PNG the plane's ray distances in the Blender
// encoding (8 (1 - v / 255)). A grid of points on that plane scores F = 1 at tau 0.1 (the truth's
// points lie 0.128 apart); the same grid lifted by 0.3 scores F = 0 and an accuracy of ~0.3. As a
// mesh, the plane's depth seen from the camera is off by exactly its lift.
TEST(MetricsCli, GeometryAgainstABlenderScenesDepthMaps) {
  if (!cli_available()) GTEST_SKIP() << "ABLENERF_BIN not built";
  test::TempDir t("metrics");
  std::filesystem::create_directories(t / "scene/test");
  const int side = 16;
  const double angle = 0.5, f = 0.5 * side / std::tan(0.5 * angle);
  test::write_file(t / "scene/transforms_test.json",
                   R"({"camera_angle_x": 0.5, "frames": [{"file_path": "./test/r_0", "transform_matrix": )"
                   R"([[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]}]})");
  write_png(t / "scene/test/r_0.png", torch::full({side, side, 4}, 255, torch::kUInt8));
  auto depth = torch::zeros({side, side, 4}, torch::kUInt8);
  for (int r = 0; r < side; ++r)
    for (int c = 0; c < side; ++c) {
      const double x = (c + 0.5 - side / 2.0) / f, y = (r + 0.5 - side / 2.0) / f;
      const double ray = 4.0 * std::sqrt(1 + x * x + y * y);
      depth.index_put_({r, c}, static_cast<int>(std::lround(255.0 * (1.0 - ray / 8.0))));
    }
  write_png(t / "scene/test/r_0_depth_0001.png", depth);
  for (const double z : {0.0, 0.3}) {
    std::ostringstream ply;
    ply << "ply\nformat ascii 1.0\nelement vertex " << 101 * 101
        << "\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
    for (int i = -50; i <= 50; ++i)
      for (int k = -50; k <= 50; ++k) ply << 0.02 * i << " " << 0.02 * k << " " << z << "\n";
    test::write_file(t / "plane.ply", ply.str());
    auto r = test::run_cli("metrics --geometry " + t / "plane.ply" + " --truth " + t / "scene" + " --tau 0.1");
    if (r.output.find("no geometry scoring") != std::string::npos) GTEST_SKIP() << "built without Open3D";
    ASSERT_EQ(r.exit_code, 0) << r.output;
    const auto j = nlohmann::json::parse(r.output);
    EXPECT_NE(j["truth"].get<std::string>().find("depth maps"), std::string::npos) << r.output;
    EXPECT_EQ(j["samples"].get<int64_t>(), side * side);
    EXPECT_FALSE(j.contains("mesh_depth")) << "points have no depth to cast";
    // The same plane as a mesh of two triangles (1.5 across each way): cast from the camera, its
    // depth is 4 - z at every pixel, the truth's 4 to within the 8-bit step.
    test::write_file(t / "square.ply",
                     "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                     "property float z\nelement face 2\nproperty list uchar int vertex_indices\n"
                     "end_header\n-1.5 -1.5 " +
                         std::to_string(z) + "\n1.5 -1.5 " + std::to_string(z) + "\n1.5 1.5 " + std::to_string(z) +
                         "\n-1.5 1.5 " + std::to_string(z) + "\n3 0 1 2\n3 0 2 3\n");
    r = test::run_cli("metrics --geometry " + t / "square.ply" + " --truth " + t / "scene" + " --tau 0.1");
    ASSERT_EQ(r.exit_code, 0) << r.output;
    const auto m = nlohmann::json::parse(r.output).at("mesh_depth");
    EXPECT_EQ(m["surface_pixels"].get<int64_t>(), side * side) << r.output;
    EXPECT_DOUBLE_EQ(m["hit_share"].get<double>(), 1.0) << r.output;
    EXPECT_NEAR(m["depth_mae"].get<double>(), z, 0.016) << r.output;
    if (z == 0.0) {
      EXPECT_GT(j["fscore"].get<double>(), 0.99) << r.output;
      EXPECT_LT(j["accuracy_mean"].get<double>(), 0.08) << r.output;
    } else {
      EXPECT_EQ(j["fscore"].get<double>(), 0.0) << r.output;
      EXPECT_NEAR(j["accuracy_mean"].get<double>(), 0.3, 0.03) << r.output;
    }
  }
}

// --cameras against a synth scene's true training cameras (eval/pose_error.h): three cameras, one of
// them turned by 3 degrees about its own centre in the estimate, so the mean rotation error is 1
// degree and the centres agree; then the one-line refusals naming file and field.
TEST(MetricsCli, PosesAgainstTheTrueCameras) {
  if (!cli_available()) GTEST_SKIP() << "ABLENERF_BIN not built";
  test::TempDir t("metrics");
  using json = nlohmann::json;
  const auto camera = [](double deg, double x) {  // turned about the y axis, centre (x, 0, 4)
    const double a = deg * M_PI / 180.0;
    return json{{std::cos(a), 0, std::sin(a), x}, {0, 1, 0, 0}, {-std::sin(a), 0, std::cos(a), 4}, {0, 0, 0, 1}};
  };
  json scene = {{"objects", {{{"shape", "sphere"}, {"centre", {0, 0, 0}}, {"radius", 0.5}}}},
                {"train_view_truth", json::array()}};
  json frames = json::array();
  for (int i = 0; i < 3; ++i) {
    scene["train_view_truth"].push_back({{"true_transform_matrix", camera(0, i - 1.0)}});
    frames.push_back({{"file_path", "r_" + std::to_string(i)}, {"transform_matrix", camera(i == 1 ? 3 : 0, i - 1.0)}});
  }
  test::write_file(t / "scene/scene.json", scene.dump());
  test::write_file(t / "est.json", json{{"frames", frames}}.dump());
  auto r = test::run_cli("metrics --cameras " + (t / "est.json") + " --truth " + (t / "scene"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto j = json::parse(r.output);
  EXPECT_EQ(j["cameras"], 3);
  EXPECT_NEAR(j["as_given"]["rotation_deg"].get<double>(), 1.0, 1e-9);
  EXPECT_NEAR(j["as_given"]["centre"].get<double>(), 0.0, 1e-12);
  EXPECT_GT(j["as_given"]["reprojection_deg"].get<double>(), 0.5);
  EXPECT_TRUE(j["aligned"]["reprojection_deg"].is_number());

  frames.erase(frames.begin());
  test::write_file(t / "two.json", json{{"frames", frames}}.dump());
  r = test::run_cli("metrics --cameras " + (t / "two.json") + " --truth " + (t / "scene"));
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("two.json"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("frames"), std::string::npos) << r.output;
  frames[0]["transform_matrix"] = {{1, 0, 0}};
  frames.push_back(frames[1]);
  test::write_file(t / "bad.json", json{{"frames", frames}}.dump());
  r = test::run_cli("metrics --cameras " + (t / "bad.json") + " --truth " + (t / "scene"));
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("frames[0].transform_matrix"), std::string::npos) << r.output;
  scene.erase("train_view_truth");
  test::write_file(t / "plain/scene.json", scene.dump());
  r = test::run_cli("metrics --cameras " + (t / "est.json") + " --truth " + (t / "plain"));
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("train_view_truth"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace ablenerf
