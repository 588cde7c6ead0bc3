// The exit codes `ablenerf train` returns after unwinding (no std::exit): 130 with a checkpoint
// after SIGINT, 3 with one error line when training diverges.
#include <gtest/gtest.h>
#include <signal.h>
#include <torch/torch.h>

#include <chrono>
#include <filesystem>
#include <thread>

#include "model/able_nerf.h"
#include "reliability/reliability_util.h"
#include "run/run_folder.h"
#include "test_util.h"
#include "train/checkpoint.h"
#include "model/model_config.h"

using namespace ablenerf;
namespace fs = std::filesystem;

namespace {

std::vector<std::string> train_args(const std::string& data, const std::string& out,
                                    const std::vector<std::string>& sets) {
  std::vector<std::string> a{"train", "--data", data, "--out", out};
  auto tiny = test::tiny_train_args();
  a.insert(a.end(), tiny.begin(), tiny.end());
  for (const auto& kv : sets) {
    a.push_back("--set");
    a.push_back(kv);
  }
  return a;
}

std::string synth_data(const test::TempDir& t) {
  const std::string data = t / "data";
  const auto s = test::run_cli("synth --out " + data + " --res 16 --train-views 2 --test-views 1");
  EXPECT_EQ(s.exit_code, 0) << s.output;
  return data;
}

}  // namespace

TEST(ExitCodes, SigintCheckpointsAndExits130) {
  test::TempDir t("ablenerf_sigint");
  const std::string data = synth_data(t);
  const std::string run = t / "run";
  // Far more steps than the test waits for, no periodic checkpoint: the one on disk afterwards is
  // the interrupt's.
  test::ChildProcess child(train_args(data, run, {"train.steps=1000000", "train.ckpt_every=0"}), t / "train.log");
  // The first log line means training runs (the handler is installed before the loop starts).
  const auto start = std::chrono::steady_clock::now();
  while (!fs::exists(run + "/log.jsonl") && !child.finished() &&
         std::chrono::steady_clock::now() - start < std::chrono::seconds(120))
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  ASSERT_TRUE(fs::exists(run + "/log.jsonl")) << test::read_text(t / "train.log");
  ASSERT_TRUE(child.send_signal(SIGINT)) << test::read_text(t / "train.log");
  EXPECT_EQ(child.wait(), 130) << test::read_text(t / "train.log");
  EXPECT_NE(test::read_text(t / "train.log").find("interrupted; checkpoint saved"), std::string::npos)
      << test::read_text(t / "train.log");
  const RunFolder r = RunFolder::open(run);
  AbleNerf model(r.config.get<ModelConfig>());
  torch::optim::Adam optim(model->parameters(), torch::optim::AdamOptions(1e-3));
  EXPECT_GE(load_checkpoint(r.checkpoint_path(), r.config, model, optim).step, 1);
}

TEST(ExitCodes, DivergedTrainingExits3WithOneErrorLine) {
  test::TempDir t("ablenerf_diverge");
  const std::string data = synth_data(t);
  // An absurd learning rate: the weights overflow within a few steps.
  test::ChildProcess child(train_args(data, t / "run",
                                      {"train.lr_init=1e30", "train.lr_final=1e30", "train.lr_warmup_steps=0",
                                       "train.steps=50", "train.max_bad_steps=3"}),
                           t / "train.log");
  EXPECT_EQ(child.wait(), 3) << test::read_text(t / "train.log");
  const std::string out = test::read_text(t / "train.log");
  const auto pos = out.find("error: training diverged: 3 consecutive non-finite steps");
  ASSERT_NE(pos, std::string::npos) << out;
  EXPECT_EQ(out.find("error:", pos + 1), std::string::npos) << out;  // one error line
}
