// Trainer::step, the one training step of the project, against an independent formula: the first
// Adam step moves every weight by -lr * g / (|g| + eps) (bias-corrected moments of one gradient),
// with g the gradient of the weighted MSE of the step's rays, computed here by hand. Also: the
// progress line follows a time budget; a one-process run with a budget ends in it.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include "data/dataset.h"
#include "train/adam.h"
#include "train/lr_schedule.h"
#include "train/ray_batch.h"
#include "train/trainer.h"
#include "train_fixture.h"
#include "util/progress.h"
#include "train/train_config.h"
#include "data/data_config.h"

using namespace ablenerf;

namespace {

// A 6x5 two-view split with random colours and two poses looking at the origin.
Split small_split() {
  torch::manual_seed(3);
  Split s;
  s.name = "train";
  s.images = torch::rand({2, 5, 6, 3});
  s.c2w = torch::tensor({{1.f, 0.f, 0.f, 0.f, 0.f, 1.f, 0.f, 0.f, 0.f, 0.f, 1.f, 4.f},
                         {0.f, 0.f, 1.f, 4.f, 0.f, 1.f, 0.f, 0.f, -1.f, 0.f, 0.f, 0.f}})
              .view({2, 3, 4});
  return s;
}

Intrinsics small_k() {
  Intrinsics k;
  k.width = 6;
  k.height = 5;
  k.fx = k.fy = 7.0;
  k.cx = 3.0;
  k.cy = 2.5;
  return k;
}

}  // namespace

TEST(TrainerStep, FirstStepIsTheClosedFormAdamStep) {
  const test::IntraOpThreads threads(1);
  Config c = test::tiny_config();
  c.set("train.rays_per_step=20");
  c.set("train.micro_batch=8");  // three micro-batches: 8 + 8 + 4
  c.set("train.coarse_weight=0.5");
  TrainOptions o;
  o.quiet = true;
  Trainer t(c, o);
  t.setup(small_split(), small_k());
  AbleNerf& model = t.model();
  std::vector<torch::Tensor> before;
  for (const auto& p : model->parameters()) before.push_back(p.detach().clone());

  // The reference gradient: the same rays (the sampler's stream, seeded alike), one forward of the
  // whole batch, the loss written out.
  RaySampler sampler(small_split(), small_k(), torch::kCPU, static_cast<uint64_t>(c.get<TrainConfig>().seed));
  const RayBatch batch = sampler.gather(sampler.draw(20));
  const auto out = model->forward(batch.rays, c.get<DataConfig>().near, c.get<DataConfig>().far);
  const auto loss = 0.5 * (out.rgb_coarse - batch.target).pow(2).mean() + (out.rgb_fine - batch.target).pow(2).mean();
  const auto params = model->parameters();
  const auto grads = torch::autograd::grad({loss}, params, {}, false, false, /*allow_unused=*/true);

  const StepReport r = t.step();
  EXPECT_EQ(r.step, 1);
  EXPECT_TRUE(r.finite);
  EXPECT_NEAR(r.loss, loss.item<double>(), 1e-5);
  const double lr = LrSchedule(c.get<TrainConfig>())(0);
  EXPECT_DOUBLE_EQ(r.lr, lr);
  EXPECT_EQ(t.steps_done(), 1);
  // Adam's first step moves each weight by about lr times the sign of its gradient, whatever the
  // gradient's scale; its moments are the gradient's own: (1 - beta1) g and (1 - beta2) g^2.
  const auto& tc = c.get<TrainConfig>();
  int moved = 0, moments = 0;
  for (size_t i = 0; i < params.size(); ++i) {
    if (!grads[i].defined()) continue;
    const auto expect = before[i] - lr * grads[i] / (grads[i].abs() + 1e-8);
    EXPECT_LT((params[i].detach() - expect).abs().max().item<double>(), 1e-5 * lr + 1e-7) << "parameter " << i;
    moved += (params[i].detach() - before[i]).abs().max().item<double>() > 0.5 * lr;
    const auto& s = t.optimiser().state_of(params[i]);
    const auto g = grads[i].detach();
    const double scale = g.abs().max().item<double>();
    EXPECT_LT((s.exp_avg() - (1 - tc.adam_beta1) * g).abs().max().item<double>(), 1e-5 * scale + 1e-12)
        << "parameter " << i;
    EXPECT_LT((s.exp_avg_sq() - (1 - tc.adam_beta2) * g * g).abs().max().item<double>(), 2e-5 * scale * scale + 1e-20)
        << "parameter " << i;
    ++moments;
  }
  EXPECT_GT(moved, 5);  // the step really moved weights, by about lr each
  EXPECT_GT(moments, 5);
}

TEST(TrainerStep, NonFiniteStepIsSkipped) {
  Config c = test::tiny_config();
  TrainOptions o;
  o.quiet = true;
  Trainer t(c, o);
  Split s = small_split();
  s.images.fill_(NAN);  // NaN targets: a NaN loss and NaN gradients
  t.setup(s, small_k());
  std::vector<torch::Tensor> before;
  for (const auto& p : t.model()->parameters()) before.push_back(p.detach().clone());
  const StepReport r = t.step();
  EXPECT_FALSE(r.finite);
  const auto params = t.model()->parameters();
  for (size_t i = 0; i < params.size(); ++i) EXPECT_TRUE(torch::equal(params[i].detach(), before[i])) << i;
}

TEST(Progress, PercentageAndEtaFollowTheFraction) {
  Progress p("train", 100000, 0.0);
  testing::internal::CaptureStderr();
  p.update(10, "", true, 0.25);  // 10 of 100000 steps, but a quarter of the budget spent
  const std::string line = testing::internal::GetCapturedStderr();
  EXPECT_NE(line.find("(25.0%)"), std::string::npos) << line;
  EXPECT_EQ(line.find("(0.0%)"), std::string::npos) << line;
}
