// The live viewer attached to a training run (`train --view`): pause holds the training thread
// between steps (and a render still answers), a checkpoint asked for while paused is written at
// once, resume lets the run finish, and an idle viewer costs no weight copies: only renders ask
// for the trainer's weights.
#include <gtest/gtest.h>
#include <httplib.h>
#include <torch/torch.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <thread>

#include "eval/eval_fixtures.h"
#include "test_util.h"
#include "train/trainer.h"
#include "view/view_server.h"

using namespace ablenerf;
namespace fs = std::filesystem;

namespace {

bool eventually(const std::function<bool()>& f) {
  for (int i = 0; i < 600; ++i) {
    if (f()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  return false;
}

}  // namespace

TEST(LiveView, PauseSaveResumeAndNoCopiesWhileIdle) {
  test::TempDir t;
  test::make_tiny_scene(t / "scene", 4, 2, 16, 16, false);
  Config c = test::tiny_model_config();
  for (const char* kv : {"train.steps=60", "train.rays_per_step=32", "train.micro_batch=32", "train.lr_warmup_steps=2",
                         "train.ckpt_every=0", "train.log_every=1", "train.eval_every=0"})
    c.set(kv);
  c.validate();
  TrainOptions o;
  o.data_dir = t / "scene";
  o.out_dir = t / "run";
  o.quiet = true;
  std::unique_ptr<ViewSession> session;
  LiveControl control;
  std::atomic<int64_t> hook_calls{0};
  o.between_steps = [&](Trainer& tr) {
    ++hook_calls;
    if (session) view_between_steps(tr, *session, control);
  };
  Trainer trainer(c, o);
  trainer.setup();
  session = std::make_unique<ViewSession>(t / "run", torch::kCPU, /*live=*/true);
  ViewServer server(*session, "127.0.0.1", 0, &control);
  const int port = server.bind();
  const ServingThread serving(server);
  httplib::Client cli("127.0.0.1", port);

  control.pause();  // before the first step: the run stops after step 1
  std::atomic<bool> done{false};
  TrainResult result = TrainResult::Interrupted;
  std::thread training([&] {
    result = trainer.run();
    done = true;
  });
  ASSERT_TRUE(eventually([&] { return hook_calls.load() >= 1; }));
  const int64_t held = trainer.steps_done();
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  EXPECT_EQ(trainer.steps_done(), held);  // paused: no step while we waited
  EXPECT_FALSE(done.load());
  auto st = cli.Get("/api/state");
  ASSERT_TRUE(st);
  const auto state = nlohmann::json::parse(st->body);
  EXPECT_TRUE(state.at("paused").get<bool>());
  EXPECT_TRUE(state.at("live").get<bool>());
  EXPECT_EQ(state.at("step"), held);  // the weights shown are those of the paused step
  EXPECT_EQ(session->weight_copies(), 1);
  // A render answers while paused.
  const std::string pose = "1,0,0,0,0,1,0,0,0,0,1,4";
  auto r = cli.Get(("/api/render?w=8&h=8&pose=" + pose).c_str());
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200);
  // Save while paused: written without resuming.
  ASSERT_FALSE(fs::exists(t / "run/checkpoint.pt"));
  ASSERT_TRUE(cli.Get("/api/control?action=save"));
  EXPECT_TRUE(eventually([&] { return fs::exists(t / "run/checkpoint.pt"); }));
  EXPECT_EQ(trainer.steps_done(), held);
  // The loss curve is served from the log.
  auto log = cli.Get("/api/log");
  ASSERT_TRUE(log);
  EXPECT_GE(nlohmann::json::parse(log->body).size(), 1u);
  // Resume: the run finishes; the render above asked for weights once more, nothing else did.
  auto resumed = cli.Get("/api/control?action=resume");
  ASSERT_TRUE(resumed);
  EXPECT_EQ(resumed->status, 200);
  ASSERT_TRUE(eventually([&] { return done.load(); }));
  training.join();
  EXPECT_EQ(result, TrainResult::Finished);
  EXPECT_EQ(trainer.steps_done(), 60);
  EXPECT_EQ(session->weight_copies(), 2);
  EXPECT_EQ(hook_calls.load(), 60);
  // A bad action is refused with one line.
  auto bad = cli.Get("/api/control?action=explode");
  ASSERT_TRUE(bad);
  EXPECT_EQ(bad->status, 400);
}
