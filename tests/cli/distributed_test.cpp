// Data-parallel training over c10d/Gloo on loopback: two processes give the weights of one process
// with the same global batch and seed (to all-reduce rounding), and a dead rank makes the survivor
// fail with a clear message instead of hanging.
#include <gtest/gtest.h>
#include <torch/torch.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <random>

#include "model/able_nerf.h"
#include "test_util.h"

using namespace ablenerf;
namespace fs = std::filesystem;

namespace {

const char* kTiny =
    " --set model.width=16 --set model.heads=1 --set model.ff_ratio=1 --set model.coarse_layers=1"
    " --set model.fine_layers=1 --set model.samples=8 --set model.le_count=2 --set model.le_layers=1"
    " --set train.rays_per_step=64 --set train.micro_batch=64 --set train.eval_every=0 --set train.log_every=5"
    " --set train.lr_warmup_steps=2 --set train.lr_decay_steps=0 --device cpu";

int free_port() {
  std::random_device rd;
  return 20000 + static_cast<int>(rd() % 30000);
}

std::string env(int rank, int world, int port) {
  return "OMP_NUM_THREADS=1 RANK=" + std::to_string(rank) + " WORLD_SIZE=" + std::to_string(world) +
         " LOCAL_RANK=" + std::to_string(rank) + " MASTER_ADDR=127.0.0.1 MASTER_PORT=" + std::to_string(port) + " ";
}

std::string bin() { return std::getenv("ABLENERF_BIN"); }

// Trains 20 steps in one process and in two with `extra` settings; the weights must agree to
// all-reduce rounding.
void expect_two_processes_equal_one(const std::string& extra) {
  test::TempDir t;
  ASSERT_EQ(test::run_cli("synth --out " + t.path() + "/data --res 16 --train-views 4 --test-views 1").exit_code, 0);
  const std::string common =
      std::string(" train --data ") + t.path() + "/data" + kTiny + " --set train.steps=20" + extra;
  auto one = test::run_cli(common + " --out " + t.path() + "/one");
  ASSERT_EQ(one.exit_code, 0) << one.output;
  const int port = free_port();
  // Two ranks in the background, through the shell; each writes its own log.
  const std::string cmd = "cd " + t.path() + " && (" + env(1, 2, port) + bin() + common +
                          " --out two > r1.log 2>&1 &) && " + env(0, 2, port) + bin() + common +
                          " --out two > r0.log 2>&1; echo $? > r0.rc; sleep 1";
  ASSERT_EQ(std::system(cmd.c_str()), 0);
  std::ifstream rc(t.path() + "/r0.rc");
  int code = -1;
  rc >> code;
  ASSERT_EQ(code, 0) << test::run_cli("--version").output;
  auto a = read_weights_dict(t.path() + "/one/weights.pt"), b = read_weights_dict(t.path() + "/two/weights.pt");
  ASSERT_EQ(a.size(), b.size());
  double worst = 0;
  for (const auto& kv : a) {
    auto ta = kv.value().toTensor(), tb = b.at(kv.key()).toTensor();
    worst = std::max(worst, (ta - tb).abs().max().item<double>());
  }
  // 20 Adam steps of lr <= 5e-4 move weights by up to ~1e-2; summation order differences stay
  // orders of magnitude below that.
  EXPECT_LT(worst, 2e-5);
  EXPECT_TRUE(fs::exists(t.path() + "/two/checkpoint.pt"));
  // Not a vacuous comparison: the group really trained 20 steps (rank 0 logged them).
  std::ifstream lg(t.path() + "/two/log.jsonl");
  std::string line, last;
  while (std::getline(lg, line)) last = line;
  EXPECT_NE(last.find("\"step\":20"), std::string::npos) << last;
}

}  // namespace

TEST(Distributed, TwoProcessesEqualOneProcess) { expect_two_processes_equal_one(""); }

// With the error map every rank needs every ray's error to draw the same next batch: the errors
// travel in the gradient all-reduce. Ranks that disagreed would train on other rays than one
// process does, far beyond the rounding bound.
TEST(Distributed, TwoProcessesEqualOneProcessWithTheErrorMap) {
  expect_two_processes_equal_one(" --set train.ray_sampling=error --set train.error_tile=2");
}

// Under a launcher (WORLD_SIZE set, as torchrun does even for one process) a single process joins a
// group of one and runs the collective path; its all-reduce is the identity, so the weights equal a
// launcher-free run's bit for bit.
TEST(Distributed, OneProcessGroupEqualsNoGroup) {
  test::TempDir t;
  ASSERT_EQ(test::run_cli("synth --out " + t.path() + "/data --res 16 --train-views 4 --test-views 1").exit_code, 0);
  const std::string common = std::string(" train --data ") + t.path() + "/data" + kTiny + " --set train.steps=10";
  // Both single-threaded (env() sets OMP_NUM_THREADS=1), so BLAS sums in the same order.
  const std::string plain = "cd " + t.path() + " && OMP_NUM_THREADS=1 " + bin() + common + " --out plain > p.log 2>&1";
  ASSERT_EQ(std::system(plain.c_str()), 0);
  const std::string cmd =
      "cd " + t.path() + " && " + env(0, 1, free_port()) + bin() + common + " --out group > g.log 2>&1";
  ASSERT_EQ(std::system(cmd.c_str()), 0);
  auto a = read_weights_dict(t.path() + "/plain/weights.pt"), b = read_weights_dict(t.path() + "/group/weights.pt");
  ASSERT_EQ(a.size(), b.size());
  ASSERT_GT(a.size(), 0u);
  for (const auto& kv : a)
    EXPECT_TRUE(torch::equal(kv.value().toTensor(), b.at(kv.key()).toTensor())) << kv.key().toStringRef();
  // The launched run really went through the group.
  std::ifstream lg(t.path() + "/g.log");
  const std::string log((std::istreambuf_iterator<char>(lg)), std::istreambuf_iterator<char>());
  EXPECT_NE(log.find("c10d group of 1 process"), std::string::npos) << log;
}

// With a time budget the ranks follow the group's agreed clock: they take the same schedule and
// stop at the same step (a rank stopping alone would leave the other waiting in an all-reduce
// until the collective timeout fails it).
TEST(Distributed, TwoProcessesShareATimeBudget) {
  test::TempDir t;
  ASSERT_EQ(test::run_cli("synth --out " + t.path() + "/data --res 16 --train-views 4 --test-views 1").exit_code, 0);
  const std::string common = std::string(" train --data ") + t.path() + "/data" + kTiny +
                             " --set train.steps=1000000 --set train.time_budget_s=4 --set train.ckpt_every=0"
                             " --dist-timeout 30";
  const int port = free_port();
  const std::string cmd = "cd " + t.path() + " && (" + env(1, 2, port) + "timeout 90 " + bin() + common +
                          " --out run > r1.log 2>&1; echo $? > r1.rc) & cd " + t.path() + " && " + env(0, 2, port) +
                          "timeout 90 " + bin() + common + " --out run > r0.log 2>&1; echo $? > r0.rc; wait";
  std::system(cmd.c_str());
  for (const char* r : {"r0", "r1"}) {
    std::ifstream rc(t.path() + "/" + r + ".rc");
    int code = -1;
    rc >> code;
    std::ifstream lg(t.path() + "/" + r + ".log");
    const std::string log((std::istreambuf_iterator<char>(lg)), std::istreambuf_iterator<char>());
    EXPECT_EQ(code, 0) << r << ": " << log;
    if (std::string(r) == "r0") {
      EXPECT_NE(log.find("time budget of 4 s spent"), std::string::npos) << log;
    }
  }
  EXPECT_TRUE(fs::exists(t.path() + "/run/checkpoint.pt"));
}

TEST(Distributed, DeadRankFailsTheOthersWithAMessage) {
  test::TempDir t;
  ASSERT_EQ(test::run_cli("synth --out " + t.path() + "/data --res 16 --train-views 2 --test-views 1").exit_code, 0);
  const std::string common =
      std::string(" train --data ") + t.path() + "/data" + kTiny + " --set train.steps=1000000 --dist-timeout 20";
  const int port = free_port();
  // Rank 1 is killed with SIGKILL after a few seconds; rank 0 must fail on its own, well before
  // the test's limit.
  const auto start = std::chrono::steady_clock::now();
  const std::string cmd = "cd " + t.path() + " && (" + env(1, 2, port) + "timeout -s KILL 6 " + bin() + common +
                          " --out run > r1.log 2>&1 &) && " + env(0, 2, port) + "timeout 120 " + bin() + common +
                          " --out run > r0.log 2>&1; echo $? > r0.rc";
  std::system(cmd.c_str());
  const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::ifstream rc(t.path() + "/r0.rc");
  int code = -1;
  rc >> code;
  std::ifstream lg(t.path() + "/r0.log");
  const std::string log((std::istreambuf_iterator<char>(lg)), std::istreambuf_iterator<char>());
  EXPECT_NE(code, 0) << log;
  EXPECT_NE(code, 124) << "rank 0 hung until the outer timeout: " << log;
  EXPECT_LT(secs, 110);
  EXPECT_NE(log.find("rank 0"), std::string::npos) << log;
  EXPECT_NE(log.find("died or timed out"), std::string::npos) << log;
}
