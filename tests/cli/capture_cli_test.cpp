// A capture's run through the built CLI ($ABLENERF_BIN): `render --cameras FILE` with a pose in
// the capture's own coordinates (moved through RUN/scene.json) renders exactly the view `eval`
// renders for that frame; the run records the scene frame and the resolved scene kind.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <filesystem>
#include <nlohmann/json.hpp>

#include "test_util.h"
#include "util/fs.h"
#include "util/image_io.h"

using namespace ablenerf;
using nlohmann::json;

TEST(CliCapture, RenderWithTheCapturesOwnPoseEqualsEvalsView) {
  test::TempDir t;
  auto r = test::run_cli("synth --out " + t / "cap" +
                         " --res 16 --train-views 6 --test-views 2 --layout nerfstudio --threads 1");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = test::run_cli("train --data " + t / "cap" + " --config " + test::source_dir() +
                    "/configs/demo.toml --set train.steps=4 --set train.time_budget_s=0 --set train.eval_every=0"
                    " --set data.scene=bounded --out " +
                    t / "run");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const json scene = json::parse(read_file(t / "run/scene.json"));
  EXPECT_EQ(scene.at("scene"), "bounded");
  EXPECT_NE(scene.at("scale").get<double>(), 1.0);  // a real transform, not the identity
  r = test::run_cli("eval --run " + t / "run" + " --max-images 1");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  // The first test frame's pose as the capture wrote it, with the capture's camera.
  const json cap = json::parse(read_file(t / "cap/transforms.json"));
  json frame;
  for (const auto& f : cap.at("frames"))
    if (f.at("file_path") == cap.at("test_filenames")[0]) frame = f;
  ASSERT_FALSE(frame.is_null());
  json cams{{"fl_x", cap.at("fl_x")},
            {"fl_y", cap.at("fl_y")},
            {"cx", cap.at("cx")},
            {"cy", cap.at("cy")},
            {"w", cap.at("w")},
            {"h", cap.at("h")},
            {"frames", json::array({{{"file_path", "x"}, {"transform_matrix", frame.at("transform_matrix")}}})}};
  test::write_file(t / "cams.json", cams.dump());
  r = test::run_cli("render --run " + t / "run" + " --cameras " + t / "cams.json" + " --out " + t / "out");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto a = read_png(t / "out/frame_0000.png").to(torch::kInt);
  const auto b = read_png(t / "run/eval/test/r_0.png").to(torch::kInt);
  ASSERT_EQ(a.sizes(), b.sizes());
  EXPECT_LE((a - b).abs().max().item<int>(), 1);             // float32 poses through the scene frame and back
  EXPECT_GT(b.to(torch::kFloat).std().item<double>(), 1.0);  // not a blank image

  // The same pose moved into the scene frame by hand (x_scene = scale R (x - centre), axes R c),
  // twice, as a path recorded in the viewer: `render --path FILE.json` gives eval's view again.
  const auto R = scene.at("rotation").get<std::vector<double>>();
  const auto centre = scene.at("centre").get<std::vector<double>>();
  const double scale = scene.at("scale").get<double>();
  const auto m = frame.at("transform_matrix");
  std::vector<double> p(12);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) {
      double v = 0;
      for (int k = 0; k < 3; ++k)
        v += R[static_cast<size_t>(3 * r + k)] *
             (m[k][c].get<double>() - (c == 3 ? centre[static_cast<size_t>(k)] : 0.0));
      p[static_cast<size_t>(4 * r + c)] = c == 3 ? scale * v : v;
    }
  test::write_file(t / "path.json", json{{"ablenerf_path", 1}, {"coordinates", "scene"}, {"poses", {p, p}}}.dump());
  r = test::run_cli("render --run " + t / "run" + " --path " + t / "path.json" + " --out " + t / "path_out");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_TRUE(std::filesystem::exists(t / "path_out/frame_0001.png"));
  EXPECT_LE((read_png(t / "path_out/frame_0000.png").to(torch::kInt) - b).abs().max().item<int>(), 1);
  // A path file in another frame is refused with one line naming the field.
  test::write_file(t / "bad_path.json", json{{"ablenerf_path", 1}, {"coordinates", "capture"}, {"poses", {p}}}.dump());
  r = test::run_cli("render --run " + t / "run" + " --path " + t / "bad_path.json" + " --out " + t / "bad_out");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("coordinates"), std::string::npos) << r.output;
}
