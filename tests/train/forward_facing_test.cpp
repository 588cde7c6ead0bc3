// Forward-facing captures end to end: the demo scene photographed LLFF-style (a grid of cameras on
// one side, all looking at it, the sky and ground at infinity behind it), written as an LLFF
// capture (poses_bounds.npy + images/), picked as "forward" by data.scene = auto, trained in NDC,
// evaluated, and rendered along the forward-facing path.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cstring>
#include <filesystem>

#include "eval/camera_path.h"
#include "eval/evaluate.h"
#include "run/run_folder.h"
#include "synth/render.h"
#include "train_fixture.h"
#include "util/image_io.h"
#include "data/data_config.h"

using namespace ablenerf;

namespace {

// Writes an LLFF capture of `res` x `res` views from a 4x3 grid of cameras 4 units in front of the
// scene (-y side), each looking at the origin.
void write_forward_capture(const std::string& dir, int res) {
  std::vector<double> rows;
  int k = 0;
  for (int j = 0; j < 3; ++j)
    for (int i = 0; i < 4; ++i, ++k) {
      const synth::Camera cam = synth::look_at_origin({-0.9 + 0.6 * i, -4.0, 0.5 + 0.4 * j}, res);
      const synth::ViewImage v = synth::render_view(cam, 2, /*environment_background=*/true);
      const auto rgba = torch::from_blob(const_cast<float*>(v.rgba.data()), {res, res, 4}, torch::kFloat);
      char name[32];
      std::snprintf(name, sizeof(name), "images/v%02d.png", k);
      std::filesystem::create_directories(dir + "/images");
      write_png(dir + "/" + name, rgba);
      // LLFF row: [down | right | back | eye | (h, w, f)] row-major, then near and far.
      const double hwf[3] = {static_cast<double>(res), static_cast<double>(res), cam.focal};
      for (int r = 0; r < 3; ++r)
        for (double x : {-cam.c2w[r][1], cam.c2w[r][0], cam.c2w[r][2], cam.c2w[r][3], hwf[r]}) rows.push_back(x);
      rows.push_back(4.0 - synth::kSceneBound);
      rows.push_back(100.0);
    }
  test::write_file(dir + "/poses_bounds.npy", test::llff_poses_bounds_npy(rows));
}

}  // namespace

TEST(ForwardFacing, LlffStyleCaptureTrainsInNdcAndRendersItsPath) {
  test::TempDir t;
  const test::IntraOpThreads threads(2);
  write_forward_capture(t / "data", 32);
  Config c = test::config_with(test::tiny_config(),
                               {"model.width=32", "model.samples=12", "model.le_count=4", "train.steps=300",
                                "train.rays_per_step=128", "train.micro_batch=128", "train.lr_init=5e-3",
                                "train.lr_final=5e-4", "train.lr_warmup_steps=20", "train.ckpt_every=0"});
  ASSERT_EQ(train(c, test::quiet_run(t / "run", t / "data")), TrainResult::Finished);
  const RunFolder run = RunFolder::open(t / "run");
  const SceneFrame scene = run.scene();
  ASSERT_EQ(scene.kind, SceneKind::ForwardFacing);  // auto, from the layout and the LLFF bounds
  EXPECT_EQ(run.config.get<DataConfig>().scene, SceneKind::ForwardFacing);
  const double psnr = test::held_out_psnr(t / "run");
  // The same capture trained as an unbounded scene (contraction, the other choice for it).
  c.set("data.scene=unbounded");
  ASSERT_EQ(train(c, test::quiet_run(t / "run_unbounded", t / "data")), TrainResult::Finished);
  const double unbounded = test::held_out_psnr(t / "run_unbounded");
  std::cout << "forward-facing capture, held-out PSNR: NDC " << psnr << " dB, unbounded " << unbounded << " dB"
            << std::endl;
  // Measured (2026-11-25, 2-vCPU VM): NDC 22.53 dB, unbounded 22.62 dB.
  EXPECT_GT(psnr, 17.0);  // learnt (an untrained model gives ~10 dB)
  EXPECT_GT(psnr, unbounded - 1.0);
  // The video path: eyes in the cameras' plane within their spread, looking at the focus point.
  const Dataset ds = Dataset::load(t / "data");
  const auto c2w = torch::cat({ds.split("train").c2w, ds.split("test").c2w});
  const auto path = forward_facing_path(PathKind::Spiral, 12, c2w);
  const auto eyes = path.select(2, 3);
  EXPECT_LE(eyes.select(1, 0).abs().max().item<double>(),
            c2w.select(2, 3).select(1, 0).abs().max().item<double>() + 1e-5);
  EXPECT_GT(eyes.select(1, 2).min().item<double>(), -1.0);  // never past the NDC near plane
  // Each path camera looks at (0, 0, -kForwardFocusDepth): its -z axis points there.
  for (int64_t i = 0; i < 12; ++i) {
    const auto to_focus = torch::tensor({0.0, 0.0, -kForwardFocusDepth}) - eyes[i];
    const auto view = -path[i].select(1, 2);
    EXPECT_NEAR((to_focus / to_focus.norm()).dot(view).item<double>(), 1.0, 1e-5);
  }
}
