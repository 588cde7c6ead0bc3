// The `eval` and `render` subcommands through the built CLI ($ABLENERF_BIN): exit codes and
// one-line errors, raw tensors equal to the PNGs, depth/branch images, video through ffmpeg, and
// --device (shared with `train`): accepted values, and a GPU asked for where there is none.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>

#include "eval/eval_fixtures.h"
#include "eval/video.h"
#include "model/able_nerf.h"
#include "run/run_folder.h"
#include "test_util.h"
#include "util/fs.h"
#include "util/image_io.h"

using namespace ablenerf;
namespace fs = std::filesystem;

namespace {

int count_lines(const std::string& s) {
  int n = 0;
  for (char c : s) n += c == '\n';
  return n;
}

torch::Tensor load_pt(const std::string& path) {
  const std::string bytes = read_file(path);
  return torch::pickle_load(std::vector<char>(bytes.begin(), bytes.end())).toTensor();
}

}  // namespace

TEST(CliEval, MissingRunExitsTwoWithOneLine) {
  const auto r = test::run_cli("eval --run /nonexistent/run");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_EQ(count_lines(r.output), 1) << r.output;
  EXPECT_NE(r.output.find("error: /nonexistent/run"), std::string::npos) << r.output;
}

TEST(CliEval, WritesMetricsAndReport) {
  test::TempDir t;
  test::make_tiny_scene(t / "scene", 2, 2, 8, 8, false);
  test::make_tiny_run(t / "run", t / "scene");
  const auto r = test::run_cli("eval --run " + t / "run" + " --max-images 1 --ssim release --chunk 13");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("LPIPS skipped"), std::string::npos) << r.output;
  EXPECT_TRUE(fs::exists(t / "run/eval/test/metrics.json"));
  EXPECT_TRUE(fs::exists(t / "run/eval/test/r_0.png"));
  EXPECT_FALSE(fs::exists(t / "run/eval/test/r_1.png"));  // --max-images 1
  EXPECT_TRUE(fs::exists(t / "run/report.html"));
  const auto bad = test::run_cli("eval --run " + t / "run" + " --split val");
  EXPECT_EQ(bad.exit_code, 2) << bad.output;
  EXPECT_EQ(count_lines(bad.output), 1) << bad.output;
}

TEST(CliRender, RawTensorsMatchThePngsAndExtrasAreWritten) {
  test::TempDir t;
  test::make_tiny_scene(t / "scene", 3, 1, 8, 8, false);
  test::make_tiny_run(t / "run", t / "scene");
  const auto r = test::run_cli("render --run " + t / "run" +
                               " --path spiral --frames 2 --width 10 --height 6 --raw --depth --branches"
                               " --le-noise 0.5 --seed 3 --out " +
                               t / "frames");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  for (const char* f :
       {"frame_0000.png", "frame_0001.png", "frame_0000_depth.png", "frame_0000_depth_mean.png",
        "frame_0000_depth_argmax.png", "frame_0000_ray.png", "frame_0000_le.png", "frame_0001.pt", "frame_0001_ray.pt"})
    EXPECT_TRUE(fs::exists(t / "frames/" + std::string(f))) << f;
  const auto raw = load_pt(t / "frames/frame_0001.pt");
  ASSERT_EQ(raw.sizes(), (std::vector<int64_t>{6, 10, 3}));
  EXPECT_EQ(raw.scalar_type(), torch::kFloat);
  const auto png = read_png(t / "frames/frame_0001.png").to(torch::kFloat) / 255.0;
  EXPECT_LE((raw - png).abs().max().item<double>(), 1.0 / 255);
  // The branch PNG is the linear tensor through the sRGB curve: check one bright-enough pixel
  // against the closed form 1.055 x^(1/2.4) - 0.055.
  const auto ray = load_pt(t / "frames/frame_0000_ray.pt");
  const auto ray_png = read_png(t / "frames/frame_0000_ray.png").to(torch::kFloat) / 255.0;
  const double x = ray[0][0][0].item<double>();
  const double expect = x <= 0.0031308 ? 12.92 * x : 1.055 * std::pow(x, 1 / 2.4) - 0.055;
  EXPECT_NEAR(ray_png[0][0][0].item<double>(), std::clamp(expect, 0.0, 1.0), 0.5 / 255 + 1e-6);
}

// --look N: the frames through training photo N's colour map (set by hand: blue halved, red + 0.3),
// against the same frames without it (raw tensors, before rounding); refused on a run without
// per-photo colour and out of range, in one line with exit code 2.
TEST(CliRender, LookOfATrainingPhoto) {
  test::TempDir t;
  test::make_tiny_scene(t / "scene", 3, 1, 8, 8, false);
  test::make_tiny_run(t / "run", t / "scene");
  const std::string common = " --path spiral --frames 1 --width 10 --height 6 --raw --out ";
  auto r = test::run_cli("render --run " + t / "run" + " --look 0" + common + t / "no");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_EQ(count_lines(r.output), 1) << r.output;
  EXPECT_NE(r.output.find("--look"), std::string::npos) << r.output;
  {
    AbleNerf model = load_run_model(RunFolder::open(t / "run"), torch::kCPU);
    model->enable_photo_colour(3);
    const torch::NoGradGuard no_grad;
    auto d = torch::zeros({3, 3, 4});
    d[1][2][2] = -0.75;  // photo 1: blue x 0.5 after centring (-0.75 + 0.25)
    d[1][0][3] = 0.45;   // red + 0.3 after centring (0.45 - 0.15)
    model->photo_colour()->parameter().copy_(d);
    save_weights(model, t / "run/weights.pt");
  }
  r = test::run_cli("render --run " + t / "run" + common + t / "mean");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = test::run_cli("render --run " + t / "run" + " --look 1" + common + t / "look");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto mean = load_pt(t / "mean/frame_0000.pt"), look = load_pt(t / "look/frame_0000.pt");
  const auto expected = (mean * torch::tensor({1.0f, 1.0f, 0.5f}) + torch::tensor({0.3f, 0.0f, 0.0f})).clamp(0, 1);
  EXPECT_LT((look - expected).abs().max().item<float>(), 1e-5);
  r = test::run_cli("render --run " + t / "run" + " --look 3" + common + t / "no");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("must be below 3"), std::string::npos) << r.output;
}

// --look N on a run with appearance codes (set by hand: photo 0's code the mean, photos 1 and 2
// opposite): photo 0's look is the mean look, photos 1 and 2 differ from it and from each other.
TEST(CliRender, LookOfATrainingPhotosAppearanceCode) {
  test::TempDir t;
  test::make_tiny_scene(t / "scene", 3, 1, 8, 8, false);
  test::make_tiny_run(t / "run", t / "scene");
  torch::manual_seed(5);
  const auto v = torch::randn({test::tiny_model_config().get<ModelConfig>().width}) * 3;
  test::give_run_appearance_codes(t / "run", torch::stack({torch::zeros_like(v), v, -v}));
  const std::string common = " --path spiral --frames 1 --width 10 --height 6 --raw --out ";
  for (const std::string look : {"mean", "0", "1", "2"}) {
    const auto r =
        test::run_cli("render --run " + t / "run" + (look == "mean" ? "" : " --look " + look) + common + t / look);
    ASSERT_EQ(r.exit_code, 0) << look << ": " << r.output;
  }
  const auto frame = [&](const std::string& look) { return load_pt(t / (look + "/frame_0000.pt")); };
  EXPECT_LT((frame("0") - frame("mean")).abs().max().item<float>(), 1e-6);
  EXPECT_GT((frame("1") - frame("mean")).abs().max().item<float>(), 1e-3);
  EXPECT_GT((frame("1") - frame("2")).abs().max().item<float>(), 1e-3);
}

TEST(CliRender, CamerasJsonAndBadOptions) {
  test::TempDir t;
  test::make_tiny_scene(t / "scene", 2, 2, 8, 8, false);
  test::make_tiny_run(t / "run", t / "scene");
  // Poses of the test split at the native size (read from the first image).
  const auto r = test::run_cli("render --run " + t / "run" + " --cameras " + t / "scene/transforms_test.json" +
                               " --out " + t / "cams");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(read_png(t / "cams/frame_0001.png").sizes(), (std::vector<int64_t>{8, 8, 3}));
  EXPECT_FALSE(fs::exists(t / "cams/frame_0002.png"));
  for (const std::string& args : {std::string(" --path helix --out ") + t / "x",
                                  std::string(" --out ") + t / "x",  // neither --path nor --cameras
                                  std::string(" --path orbit --raw --out ") + t / "x.mp4"}) {
    const auto bad = test::run_cli("render --run " + t / "run" + args);
    EXPECT_EQ(bad.exit_code, 2) << args << ": " << bad.output;
    EXPECT_EQ(count_lines(bad.output), 1) << args << ": " << bad.output;
  }
}

TEST(CliRender, VideoWithoutFfmpegExitsTwoWithOneLine) {
  test::TempDir t;
  test::make_tiny_scene(t / "scene", 2, 1, 8, 8, false);
  test::make_tiny_run(t / "run", t / "scene");
  test::ScopedEnv path("PATH", t / "empty_bin");  // no ffmpeg reachable
  const auto r = test::run_cli("render --run " + t / "run" + " --path orbit --frames 2 --out " + t / "v.mp4");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_EQ(count_lines(r.output), 1) << r.output;
  EXPECT_NE(r.output.find("ffmpeg not found"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(t / "v.mp4"));
  const auto fb =
      test::run_cli("render --run " + t / "run" + " --path orbit --frames 2 --fallback-frames --out " + t / "v.mp4");
  EXPECT_EQ(fb.exit_code, 0) << fb.output;
  EXPECT_TRUE(fs::exists(t / "v_frames/frame_0001.png"));
}

TEST(CliRender, VideoThroughFfmpeg) {
  if (!ffmpeg_available()) GTEST_SKIP() << "ffmpeg is not installed";
  test::TempDir t;
  test::make_tiny_scene(t / "scene", 2, 1, 8, 8, false);
  test::make_tiny_run(t / "run", t / "scene");
  const auto r = test::run_cli("render --run " + t / "run" +
                               " --path orbit --frames 3 --width 16 --height 16 --fps 10 --out " + t / "v.mp4");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  ASSERT_TRUE(fs::exists(t / "v.mp4"));
  EXPECT_GT(fs::file_size(t / "v.mp4"), 0u);
}

TEST(CliDevice, EvalAndRenderTakeDeviceAndRefuseMissingGpusInOneLine) {
  test::TempDir t;
  test::make_tiny_scene(t / "scene", 2, 1, 8, 8, false);
  test::make_tiny_run(t / "run", t / "scene");
  const std::string eval = "eval --run " + t / "run" + " --max-images 1";
  const std::string render =
      "render --run " + t / "run" + " --path orbit --frames 1 --width 4 --height 4 --out " + t / "f";
  const std::string train = "train --data " + t / "scene" + " --out " + t / "new_run";
  auto e = test::run_cli(eval + " --device cpu");
  EXPECT_EQ(e.exit_code, 0) << e.output;
  auto r = test::run_cli(render + " --device cpu");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_TRUE(fs::exists(t / "f/frame_0000.png"));
  std::vector<std::string> refused{"tpu", "gpu0", "meta"};
  if (!torch::cuda::is_available()) refused.insert(refused.end(), {"cuda", "cuda:1"});
  for (const std::string& cmd : {eval, render, train})
    for (const std::string& dev : refused) {
      const auto bad = test::run_cli(cmd + " --device " + dev);
      EXPECT_EQ(bad.exit_code, 2) << cmd << " --device " << dev << ": " << bad.output;
      EXPECT_EQ(count_lines(bad.output), 1) << bad.output;
      EXPECT_EQ(bad.output.rfind("error: --device: " + dev + ": ", 0), 0u) << bad.output;
    }
  EXPECT_FALSE(fs::exists(t / "new_run"));  // refused before anything was written
}

// `export --points / --mesh` end to end on the tiny run: what it wrote is named in its last line and
// opens as PLY; bad requests are refused with one line before any rendering (a run without
// weights, a bad crop, an unknown extension: exit 2; a missing output folder: exit 1), and nothing
// is left behind.
TEST(CliExport, PointsAndMeshOfATinyRunAndItsRefusals) {
  test::TempDir t;
  test::make_tiny_scene(t / "scene", 2, 1, 16, 16, false);
  test::make_tiny_run(t / "run", t / "scene");
  const std::string base = "export --run " + t / "run" + " --views 3 --max-side 16";
  const auto bad = [&](const std::string& args, int code, const std::string& named) {
    const auto r = test::run_cli(base + " " + args);
    EXPECT_EQ(r.exit_code, code) << args << ": " << r.output;
    EXPECT_NE(r.output.find(named), std::string::npos) << args << ": " << r.output;
    EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << r.output;
  };
  const auto probe = test::run_cli(base + " --points " + t / "probe.xyz");
  if (probe.output.find("libopen3d-dev") != std::string::npos) GTEST_SKIP() << "built without Open3D";
  bad("--points " + t / "p.xyz", 2, "p.xyz");
  bad("--points " + t / "p.ply --crop 0,0,0,1,1", 2, "--crop");
  bad("--points " + t / "no/such/p.ply", 1, "no/such");
  bad("--mesh " + t / "m.stl", 2, "m.stl");
  bad("--mesh " + t / "m.ply --method marching", 2, "--method");
  bad("--mesh " + t / "m.ply --resolution 100000", 2, "--resolution");
  std::filesystem::remove(t / "run/weights.pt");
  bad("--points " + t / "p.ply", 2, "weights.pt");
  for (const auto& e : std::filesystem::directory_iterator(t.path()))
    EXPECT_TRUE(e.path().filename() == "scene" || e.path().filename() == "run") << "nothing written: " << e.path();
}
