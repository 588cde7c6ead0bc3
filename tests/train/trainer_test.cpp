// The training loop: it learns, a resumed run ends with exactly the weights of an uninterrupted one
// (serially, and with the ray split), divergence stops the run with the last good checkpoint intact.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>

#include "kernels/cpu_parallel.h"
#include "run/run_folder.h"
#include "train/checkpoint.h"
#include "train/trainer.h"
#include "train_fixture.h"
#include "util/errors.h"
#include "data/data_config.h"
#include "model/model_config.h"

using namespace ablenerf;
namespace fs = std::filesystem;

namespace {

c10::Dict<c10::IValue, c10::IValue> weights_of(const std::string& run) {
  return read_weights_dict(run + "/weights.pt");
}

void expect_same_weights(const std::string& run_a, const std::string& run_b, double tol) {
  auto a = weights_of(run_a), b = weights_of(run_b);
  ASSERT_EQ(a.size(), b.size());
  for (const auto& kv : a) {
    auto ta = kv.value().toTensor(), tb = b.at(kv.key()).toTensor();
    if (tol == 0)
      EXPECT_TRUE(torch::equal(ta, tb)) << kv.key().toStringRef();
    else
      EXPECT_TRUE(torch::allclose(ta, tb, 0, tol))
          << kv.key().toStringRef() << " max diff " << (ta - tb).abs().max().item<double>();
  }
}

TrainOptions options(const std::string& out) { return test::quiet_run(out); }

// A tiny run for a time budget of `seconds`: 10^6 schedule steps (the budget ends it), lr 1e-3 ->
// 1e-4 decaying over the budget, a warm-up of `warmup_steps`, every step logged, nothing else.
Config time_budget_config(int seconds, int warmup_steps) {
  Config c = test::tiny_config();
  c.set("train.steps=1000000");
  c.set("train.lr_warmup_steps=" + std::to_string(warmup_steps));
  c.set("train.lr_decay_steps=0");
  c.set("train.lr_init=1e-3");
  c.set("train.lr_final=1e-4");
  c.set("train.log_every=1");
  c.set("train.eval_every=0");
  c.set("train.ckpt_every=0");
  c.set("train.time_budget_s=" + std::to_string(seconds));
  return c;
}

}  // namespace

TEST(Trainer, LossFallsAndRunFolderIsComplete) {
  test::TempDir t;
  Config c = test::tiny_config();
  c.set("train.steps=60");
  c.set("train.lr_init=3e-3");
  c.set("train.lr_final=1e-3");
  c.set("train.log_every=1");
  c.set("train.eval_every=30");
  c.set("train.eval_views=1");
  ASSERT_EQ(train(c, options(t / "run")), TrainResult::Finished);
  for (const char* f : {"config.toml", "run.json", "weights.pt", "checkpoint.pt", "log.jsonl"})
    EXPECT_TRUE(fs::exists(t / ("run/" + std::string(f)))) << f;
  auto log = test::read_log(t / "run");
  std::vector<double> losses;
  int evals = 0;
  for (const auto& j : log) {
    if (j["type"] == "train") losses.push_back(j["loss"].get<double>());
    if (j["type"] == "eval") {
      ++evals;
      EXPECT_TRUE(std::isfinite(j["psnr"].get<double>()));
      EXPECT_EQ(j["view_indices"], nlohmann::json::array({0}));
    }
  }
  ASSERT_EQ(losses.size(), 60u);
  EXPECT_EQ(evals, 2);
  // The run ends with its passes over the training pixels: 60 steps of the preset's rays over 4
  // views of 16 x 16 pixels.
  ASSERT_EQ(log.back()["type"], "coverage");
  EXPECT_EQ(log.back()["pixels"], 4 * 16 * 16);
  EXPECT_DOUBLE_EQ(log.back()["passes_per_pixel"].get<double>(),
                   60.0 * static_cast<double>(c.get<TrainConfig>().rays_per_step) / (4 * 16 * 16));
  // Learning the mean colour alone takes the loss clearly below its start (the first step's output
  // is about 0.25 grey against a mostly white image).
  double last = 0;
  for (size_t i = 50; i < 60; ++i) last += losses[i] / 10;
  EXPECT_LT(last, 0.7 * losses.front());
  // The run folder reopens with the same config, data.scene resolved from the dataset (a Blender
  // scene is bounded), and the scene frame beside it.
  RunFolder r = RunFolder::open(t / "run");
  Config resolved = c;
  resolved.get<DataConfig>().scene = SceneKind::Bounded;
  EXPECT_EQ(r.config.to_toml(), resolved.to_toml());
  EXPECT_EQ(r.scene().kind, SceneKind::Bounded);
  EXPECT_TRUE(r.scene().identity());
  EXPECT_EQ(r.data_dir, fs::absolute(test::tiny_dataset()).lexically_normal().string());
}

TEST(Trainer, FewPassesPerPixelGetAdviceThatReachesEnough) {
  EXPECT_DOUBLE_EQ(passes_per_pixel(1000, 256, 128000), 2.0);
  EXPECT_EQ(passes_per_pixel(10, 256, 0), 0.0);
  EXPECT_EQ(coverage_advice(kFewPasses, 8, 900, 135), "");
  EXPECT_EQ(coverage_advice(5.0, 8, 900, 135), "");
  // A third of a pass (the Ethiopian head in 15 minutes, 378 x 504 at 8): 6x the budget, or images
  // reduced sqrt(6) = 2.45 times more (8 -> 20, a short side of 151).
  const std::string a = coverage_advice(1.0 / 3.0, 8, 900, 378);
  EXPECT_NE(a.find("6x longer (--time-budget 90m)"), std::string::npos) << a;
  EXPECT_NE(a.find("--downscale 20"), std::string::npos) << a;
  // A run of steps: more steps, not a budget.
  const std::string b = coverage_advice(1.0, 1, 0, 800);
  EXPECT_NE(b.find("2x more steps"), std::string::npos) << b;
  EXPECT_NE(b.find("--downscale 2"), std::string::npos) << b;
  // Images that would fall under kSmallestAdvisedSide pixels are not advised: 100 pixels at 1
  // reduced 40 times would be 2.
  const std::string c = coverage_advice(0.00128, 1, 5, 100);
  EXPECT_NE(c.find("x longer"), std::string::npos) << c;
  EXPECT_EQ(c.find("downscale"), std::string::npos) << c;
  // The edge: 135 pixels reduced 2.45 times more keep 54 < 64; 160 keep 64.
  EXPECT_EQ(coverage_advice(1.0 / 3.0, 8, 900, 135).find("downscale"), std::string::npos);
  EXPECT_NE(coverage_advice(1.0 / 3.0, 8, 900, 160).find("--downscale 20"), std::string::npos);
}

TEST(Trainer, HeldOutViewsSpreadOverTheSplit) {
  // Lego's 200-view test orbit with 3 views: one from each third of the orbit.
  EXPECT_EQ(held_out_views(200, 3), (std::vector<int64_t>{0, 66, 133}));
  EXPECT_EQ(held_out_views(20, 4), (std::vector<int64_t>{0, 5, 10, 15}));
  EXPECT_EQ(held_out_views(5, 5), (std::vector<int64_t>{0, 1, 2, 3, 4}));
  // More views asked than the split holds: each view once.
  EXPECT_EQ(held_out_views(2, 4), (std::vector<int64_t>{0, 1}));
  EXPECT_TRUE(held_out_views(10, 0).empty());
  EXPECT_TRUE(held_out_views(0, 3).empty());
}

// With train.time_budget_s the run ends in its budget with the schedule run to its end (the learning
// rate of the last step is at lr_final), however many of train.steps it reached.
TEST(Trainer, TimeBudgetEndsTheRunWithTheScheduleComplete) {
  test::TempDir t;
  const Config c = time_budget_config(3, 0);
  ASSERT_EQ(train(c, options(t / "run")), TrainResult::Finished);
  const auto log = test::read_log(t / "run");
  ASSERT_GE(log.size(), 3u);
  const auto& first = log.front();
  // The last step's line (the run's coverage line follows it).
  auto last = log.back();
  for (const auto& j : log)
    if (j["type"] == "train") last = j;
  EXPECT_LT(last["step"].get<int64_t>(), 1000000);
  // The first step runs near lr_init, the last near lr_final (log-linear: a quarter of the budget
  // left would still be 1e-4 * 10^0.25 = 1.78e-4; the margin is for a test run beside the heavy CLI
  // suites, where one step has taken 0.5 s of the 3: 1.51e-4 measured).
  EXPECT_GT(first["lr"].get<double>(), 7e-4);
  EXPECT_LT(last["lr"].get<double>(), 1.78e-4);
  EXPECT_GE(last["lr"].get<double>(), 1e-4 * (1 - 1e-9));
  EXPECT_LT(last["elapsed_s"].get<double>(), 3.0 + 1.0);
  // A checkpoint of the final state was written, as at the end of any run.
  EXPECT_TRUE(fs::exists(t / "run/checkpoint.pt"));
}

// A time budget lays the decay over the budget, not the warm-up: with 1e6 schedule steps a warm-up of
// 10^5 steps still lasts 10^5 optimiser steps (it ended after a tenth of the budget, seconds into
// the run, when the schedule's position drove it), so the short run below stays in its warm-up.
TEST(Trainer, TimeBudgetKeepsTheWarmUpInOptimiserSteps) {
  test::TempDir t;
  Config c = time_budget_config(2, 100000);
  c.set("train.lr_warmup_mult=0.01");
  ASSERT_EQ(train(c, options(t / "run")), TrainResult::Finished);
  const auto log = test::read_log(t / "run");
  ASSERT_GE(log.size(), 3u);
  ASSERT_LT(log.back()["step"].get<int64_t>(), 5000);  // far inside the warm-up
  for (const auto& j : log) {
    if (j["type"] != "train") continue;
    // Below 8.8% of lr_init: 0.01 + 0.99 sin(pi/2 * 5000/1e5) < 0.088, times a decay factor <= 1.
    EXPECT_LT(j["lr"].get<double>(), 0.088e-3) << j.dump();
  }
}

TEST(Trainer, ResumeEqualsUninterrupted) {
  const test::IntraOpThreads threads(1);
  test::TempDir t;
  const Config c = test::tiny_config();  // 12 steps, checkpoint every 5
  // Stops between two periodic checkpoints (every 5 steps).
  test::train_straight_and_in_pieces(c, options, t.path(), 7);
  expect_same_weights(t / "straight", t / "pieces", 0.0);
}

TEST(Trainer, ResumeEqualsUninterruptedWithTheRaySplit) {
  // Two CPU threads: every 16-ray micro-batch runs as two slices with their own gradients, summed
  // in slice order, so the result depends on the thread count but not on thread timing.
  const test::IntraOpThreads threads(2);
  if (cpu_workers(16, 8) < 2) GTEST_SKIP() << "no OpenBLAS thread control: no ray split";
  test::TempDir t;
  const Config c = test::tiny_config();  // 32 rays per step in micro-batches of 16
  // Stops between two periodic checkpoints (every 5 steps).
  test::train_straight_and_in_pieces(c, options, t.path(), 7);
  expect_same_weights(t / "straight", t / "pieces", 0.0);
}

TEST(Trainer, ResumeEqualsUninterruptedWithStratifiedJitter) {
  // model.randomized draws from LibTorch's global stream, which the checkpoint carries too.
  const test::IntraOpThreads threads(1);
  test::TempDir t;
  Config c = test::tiny_config();
  c.set("model.randomized=true");
  // Stops right on a periodic checkpoint; a temporary left by a kill during a checkpoint write is
  // cleaned up on resume.
  test::train_straight_and_in_pieces(c, options, t.path(), 5,
                                     [&] { test::write_file(t / "pieces/checkpoint.pt.tmp999_0", "partial"); });
  EXPECT_FALSE(fs::exists(t / "pieces/checkpoint.pt.tmp999_0"));
  expect_same_weights(t / "straight", t / "pieces", 0.0);
}

TEST(Trainer, ResumeEqualsUninterruptedWithTheErrorMap) {
  // The error map (train.ray_sampling = "error") steers which pixels later steps draw: the
  // checkpoint carries it, so a resumed run draws the same rays as an uninterrupted one.
  const test::IntraOpThreads threads(1);
  test::TempDir t;
  Config c = test::tiny_config();
  c.set("train.ray_sampling=\"error\"");
  c.set("train.error_tile=2");
  c.set("train.error_uniform_share=0.1");
  test::train_straight_and_in_pieces(c, options, t.path(), 7);
  expect_same_weights(t / "straight", t / "pieces", 0.0);
  // Not vacuous: with uniform draws the same run ends elsewhere.
  ASSERT_EQ(train(test::tiny_config(), options(t / "uniform")), TrainResult::Finished);
  auto a = weights_of(t / "straight"), b = weights_of(t / "uniform");
  bool any_differs = false;
  for (const auto& kv : a) any_differs |= !torch::equal(kv.value().toTensor(), b.at(kv.key()).toTensor());
  EXPECT_TRUE(any_differs);
}

TEST(Trainer, ResumeEqualsUninterruptedWithCoarsePixels) {
  // Coarse pixels (train.coarse_pixel_*): how many a step draws follows the schedule, so a resumed
  // run, stopped while they are still drawn, draws the same rays as an uninterrupted one.
  const test::IntraOpThreads threads(1);
  test::TempDir t;
  Config c = test::tiny_config();  // 12 steps
  c.set("train.ray_sampling=\"error\"");
  c.set("train.coarse_pixel_share=0.8");
  c.set("train.coarse_pixel_until=0.75");  // still drawn at step 8 of 12
  test::train_straight_and_in_pieces(c, options, t.path(), 7);
  expect_same_weights(t / "straight", t / "pieces", 0.0);
  // Not vacuous: without coarse pixels the same run ends elsewhere.
  Config plain = test::tiny_config();
  plain.set("train.ray_sampling=\"error\"");
  ASSERT_EQ(train(plain, options(t / "plain")), TrainResult::Finished);
  auto a = weights_of(t / "straight"), b = weights_of(t / "plain");
  bool any_differs = false;
  for (const auto& kv : a) any_differs |= !torch::equal(kv.value().toTensor(), b.at(kv.key()).toTensor());
  EXPECT_TRUE(any_differs);
}

TEST(Trainer, DistortionTermBeginsWhereTheScheduleSays) {
  // train.distortion_start = 0.5 on a 12-step run: the step at schedule position p = s/12 (s steps
  // done) carries distortion_ramp(0.5, p) of the weight, so logged steps 1-7 (p <= 0.5) have no
  // distortion term, step 8 (p = 7/12) part of it and steps 9-12 all of it; without a start every
  // step has it.
  test::TempDir t;
  const auto distortion_by_step = [&](const Config& c, const std::string& name) {
    EXPECT_EQ(train(c, options(t / name)), TrainResult::Finished);
    std::map<int64_t, double> d;
    for (const auto& j : test::read_log(t / name))
      if (j["type"] == "train")
        d[j["step"].get<int64_t>()] = j["terms"].value("distortion", 0.0);  // terms at 0 are not logged
    return d;
  };
  const Config late = test::config_with(
      test::tiny_config(), {"train.log_every=1", "train.distortion_weight=0.5", "train.distortion_start=0.5"});
  const auto d = distortion_by_step(late, "late");
  ASSERT_EQ(d.size(), 12u);
  for (int64_t step = 1; step <= 7; ++step) EXPECT_EQ(d.at(step), 0.0) << "step " << step;
  for (int64_t step = 8; step <= 12; ++step) EXPECT_GT(d.at(step), 0.0) << "step " << step;
  const auto always = distortion_by_step(
      test::config_with(test::tiny_config(), {"train.log_every=1", "train.distortion_weight=0.5"}), "always");
  ASSERT_EQ(always.size(), 12u);
  for (const auto& [step, v] : always) EXPECT_GT(v, 0.0) << "step " << step;
}

TEST(Trainer, RefusesToOverwriteARun) {
  test::TempDir t;
  Config c = test::tiny_config();
  c.set("train.steps=1");
  train(c, options(t / "run"));
  EXPECT_THROW(train(c, options(t / "run")), InputError);
}

TEST(Trainer, DivergenceStopsWithLastGoodCheckpoint) {
  test::TempDir t;
  Config c = test::tiny_config();
  // An absurd learning rate: Adam moves every weight by ~1e30 per step, the forward overflows.
  c.set("train.lr_init=1e30");
  c.set("train.lr_final=1e30");
  c.set("train.lr_warmup_steps=0");
  c.set("train.ckpt_every=1");
  c.set("train.steps=50");
  c.set("train.max_bad_steps=3");
  try {
    train(c, options(t / "run"));
    FAIL() << "expected TrainingDiverged";
  } catch (const TrainingDiverged& e) {
    EXPECT_NE(std::string(e.what()).find("non-finite"), std::string::npos);
  }
  // The checkpoint on disk loads and is from before the bad steps.
  AbleNerf m(c.get<ModelConfig>());
  torch::optim::Adam o(m->parameters(), torch::optim::AdamOptions(1.0));
  TrainState s = load_checkpoint(t / "run/checkpoint.pt", c, m, o);
  EXPECT_LT(s.step, 50);
  for (const auto& p : m->parameters()) EXPECT_TRUE(p.isfinite().all().item<bool>());
}

TEST(Trainer, TheGpuCapturePresetKeepsTheCapturePresetsRecipe) {
  // configs/capture_gpu.toml is configs/capture.toml sized for a GPU: its image size, batch, grid
  // table and time differ; the recipe (what trains and how it is weighed) must not drift apart.
  const auto cpu = test::preset_config("capture").get<TrainConfig>(),
             gpu = test::preset_config("capture_gpu").get<TrainConfig>();
  EXPECT_EQ(gpu.coarse_le, cpu.coarse_le);
  EXPECT_EQ(gpu.coarse_view_head, cpu.coarse_view_head);
  EXPECT_EQ(gpu.coarse_weight, cpu.coarse_weight);
  EXPECT_EQ(gpu.distortion_weight, cpu.distortion_weight);
  EXPECT_EQ(gpu.distortion_start, cpu.distortion_start);
  EXPECT_EQ(gpu.distortion_forward_facing, cpu.distortion_forward_facing);
  EXPECT_EQ(gpu.grid_decay, cpu.grid_decay);
  EXPECT_EQ(gpu.proposal_attention_weight, cpu.proposal_attention_weight);
  EXPECT_EQ(gpu.lr_init, cpu.lr_init);
  EXPECT_EQ(gpu.lr_final, cpu.lr_final);
  EXPECT_EQ(gpu.ray_sampling, cpu.ray_sampling);
  // and the GPU's own: bigger steps, the CUDA graph.
  EXPECT_GT(gpu.rays_per_step, cpu.rays_per_step);
  EXPECT_TRUE(gpu.graph);
}
