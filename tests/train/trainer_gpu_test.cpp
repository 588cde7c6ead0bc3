// The device form of the training step on a GPU (skipped without CUDA): a CUDA graph replaying
// the step gives the weights of the same step run eagerly; the device Adam skips a non-finite
// step without touching weights or its step count; a resumed device-form run ends with the
// weights of an uninterrupted one.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include "train/adam.h"
#include "train/trainer.h"
#include "train_fixture.h"
#include "train/train_config.h"
#include "model/model_config.h"

using namespace ablenerf;

namespace {

bool have_gpu() { return torch::cuda::is_available() && Adam::device_form_available(torch::Device(torch::kCUDA, 0)); }

TrainOptions gpu_options(const std::string& out) {
  TrainOptions o = test::quiet_run(out);
  o.device = torch::Device(torch::kCUDA, 0);
  return o;
}

double max_weight_difference(AbleNerf& a, AbleNerf& b) {
  double worst = 0;
  const auto pa = a->parameters(), pb = b->parameters();
  for (size_t i = 0; i < pa.size(); ++i) worst = std::max(worst, (pa[i] - pb[i]).abs().max().item<double>());
  return worst;
}

// 12 steps eagerly and 12 through the captured graph on `data` with `c`: same loss and weights,
// and the weights moved from their start.
void expect_graph_equals_eager(const Config& c, const std::string& data) {
  test::TempDir t;
  Config eager_cfg = c, graph_cfg = c;
  eager_cfg.set("train.graph=false");
  graph_cfg.set("train.graph=true");
  TrainOptions eager_opts = gpu_options(t / "eager"), graph_opts = gpu_options(t / "graph");
  eager_opts.data_dir = graph_opts.data_dir = data;
  Trainer eager(eager_cfg, eager_opts);
  Trainer graph(graph_cfg, graph_opts);
  eager.setup();
  graph.setup();
  ASSERT_TRUE(eager.device_form());
  ASSERT_TRUE(graph.device_form());
  for (int i = 0; i < 12; ++i) {
    eager.step();
    graph.step();
  }
  const StepReport re = eager.flush(), rg = graph.flush();
  EXPECT_TRUE(graph.graph_captured());
  EXPECT_FALSE(eager.graph_captured());
  EXPECT_EQ(re.step, 12);
  EXPECT_EQ(rg.step, 12);
  EXPECT_NEAR(re.loss, rg.loss, 1e-5 * std::abs(re.loss));
  EXPECT_LT(max_weight_difference(eager.model(), graph.model()), 1e-5);
  // And the weights did move.
  torch::manual_seed(static_cast<uint64_t>(c.get<TrainConfig>().seed));
  AbleNerf init(c.get<ModelConfig>());
  init->to(torch::Device(torch::kCUDA, 0));
  EXPECT_GT(max_weight_difference(init, graph.model()), 1e-4);
}

// A small synthetic phone-like capture: 4 train views and 1 test view of 16x16 through an OpenCV lens,
// in nerfstudio's layout.
void write_lens_capture(const std::string& dir) {
  SynthOptions o;
  o.res = 16;
  o.train_views = 4;
  o.test_views = 1;
  o.threads = 1;
  o.lens = "opencv";
  o.layout = "nerfstudio";
  write_synthetic_dataset(dir, o);
}

// The small lens capture in the contracted scene on a small hash grid with the proposal sampler,
// plus `extra` settings: graph and eager steps agree.
void expect_graph_equals_eager_on_the_grid(std::initializer_list<const char*> extra) {
  test::TempDir data;
  write_lens_capture(data.path());
  const Config grid = test::config_with(
      test::tiny_config(), {"train.steps=12", "data.scene=unbounded", "model.embedding=grid", "model.grid_levels=4",
                            "model.grid_log2_table=12", "model.grid_max_resolution=64", "model.proposal_samples=16"});
  expect_graph_equals_eager(test::config_with(grid, extra), data.path());
}

}  // namespace

TEST(TrainerGpu, GraphEqualsEager) {
  if (!have_gpu()) GTEST_SKIP() << "no CUDA device";
  Config c = test::tiny_config();
  c.set("train.steps=12");
  expect_graph_equals_eager(c, test::tiny_dataset());
}

// A real capture's path through the captured step: rays through an OpenCV lens (Newton inverse and
// the pixel footprint's Jacobian on the device) and the contracted unbounded scene. The first GPU
// run of a capture found a host copy here that the graph capture refused.
TEST(TrainerGpu, GraphEqualsEagerThroughALensUnbounded) {
  if (!have_gpu()) GTEST_SKIP() << "no CUDA device";
  test::TempDir data;
  write_lens_capture(data.path());
  Config c = test::tiny_config();
  c.set("train.steps=12");
  c.set("data.scene=unbounded");
  c.validate();
  expect_graph_equals_eager(c, data.path());
}

// The capture preset's additions and the phone-capture options through the captured step: the hash
// grid front end and its normalised decay, the proposal sampler, per-photo colour and camera
// refinement with BARF's coarse-to-fine window (a device tensor the trainer updates before each
// replay). The first GPU run with camera refinement stopped at the capture: its rotations went
// through torch::matrix_exp, which copies norms to the host on CUDA (now a closed form).
TEST(TrainerGpu, GraphEqualsEagerWithGridProposalPhotoColourAndCameraRefinement) {
  if (!have_gpu()) GTEST_SKIP() << "no CUDA device";
  expect_graph_equals_eager_on_the_grid({"train.grid_decay=1.0", "train.photo_colour=true", "train.camera_refine=true",
                                         "train.camera_refine_focal=true", "train.camera_refine_c2f_start=0.1",
                                         "train.camera_refine_c2f_end=0.6"});
}

// The capture preset's step as configs/capture.toml trains it, through the captured step: the coarse
// colour through the view head without the coarse LE transformer (train.coarse_view_head), the
// proposal's attention loss, and mip-NeRF 360's distortion term switched on halfway through the 12
// steps (its weight a device value the replays read), all on the grid in the contracted scene.
TEST(TrainerGpu, GraphEqualsEagerWithTheCapturePresetsViewHeadAndDistortion) {
  if (!have_gpu()) GTEST_SKIP() << "no CUDA device";
  expect_graph_equals_eager_on_the_grid({"train.grid_decay=0.3", "train.coarse_le=false", "train.coarse_view_head=true",
                                         "train.proposal_attention_weight=0.01", "train.distortion_weight=0.01",
                                         "train.distortion_start=0.5", "train.ray_sampling=\"error\""});
}

// Coarse pixels first (docs/MODEL.md): the gather mixes full and reduced pixels with tensor ops and
// the error map takes a coarse pixel's error at its block's first pixel, all inside the captured
// step, while the share of coarse rays falls from step to step (the batch's shape stays fixed).
TEST(TrainerGpu, GraphEqualsEagerWithCoarsePixelsThroughALens) {
  if (!have_gpu()) GTEST_SKIP() << "no CUDA device";
  test::TempDir data;
  write_lens_capture(data.path());
  const Config c =
      test::config_with(test::tiny_config(), {"train.steps=12", "data.scene=unbounded", "train.ray_sampling=\"error\"",
                                              "train.coarse_pixel_share=0.8", "train.coarse_pixel_until=0.9"});
  expect_graph_equals_eager(c, data.path());
}

TEST(TrainerGpu, DeviceAdamSkipsNonFiniteSteps) {
  if (!have_gpu()) GTEST_SKIP() << "no CUDA device";
  const auto dev = torch::TensorOptions().device(torch::kCUDA, 0);
  auto w = torch::ones({4}, dev).requires_grad_(true);
  Adam adam({w}, 0.1, /*device_form=*/true);
  w.mutable_grad() = torch::tensor({1.f, -1.f, 2.f, 0.5f}, dev);
  adam.step_device(torch::zeros({}, dev));
  EXPECT_EQ(adam.found_inf().item<float>(), 0.f);
  // First Adam step: each weight moves by lr against the sign of its gradient.
  EXPECT_TRUE(torch::allclose(w.detach().cpu(), torch::tensor({0.9f, 1.1f, 0.9f, 0.9f}), 0, 1e-6));
  const auto after_one = w.detach().clone();
  w.mutable_grad() = torch::tensor({1.f, NAN, 2.f, 0.5f}, dev);
  adam.step_device(torch::zeros({}, dev));
  EXPECT_EQ(adam.found_inf().item<float>(), 1.f);
  EXPECT_TRUE(torch::equal(w.detach(), after_one));
  w.mutable_grad() = torch::tensor({1.f, 1.f, 1.f, 1.f}, dev);
  adam.step_device(torch::full({}, INFINITY, dev));  // a non-finite loss alone skips too
  EXPECT_EQ(adam.found_inf().item<float>(), 1.f);
  EXPECT_TRUE(torch::equal(w.detach(), after_one));
  adam.to_checkpoint();
  const auto& st = adam.optim().state();
  ASSERT_EQ(st.size(), 1u);
  EXPECT_EQ(static_cast<torch::optim::AdamParamState&>(*st.begin()->second).step(), 1);  // skips not counted
}

TEST(TrainerGpu, ResumeEqualsUninterrupted) {
  if (!have_gpu()) GTEST_SKIP() << "no CUDA device";
  test::TempDir t;
  const Config c = test::tiny_config();  // 12 steps, checkpoint every 5
  test::train_straight_and_in_pieces(c, gpu_options, t.path(), 7);
  auto a = read_weights_dict(t / "straight/weights.pt"), b = read_weights_dict(t / "pieces/weights.pt");
  for (const auto& kv : a) {
    const auto ta = kv.value().toTensor(), tb = b.at(kv.key()).toTensor();
    EXPECT_LT((ta - tb).abs().max().item<double>(), 1e-5) << kv.key().toStringRef();
  }
}
