// The learning-rate schedule at the values docs/MODEL.md, section 8 gives.
#include <gtest/gtest.h>

#include <cmath>

#include "train/lr_schedule.h"
#include "train/train_config.h"

using namespace ablenerf;

namespace {
TrainConfig release() {
  TrainConfig c;  // defaults are the release's: 5e-4 -> 1e-4 over 250k, warm-up 1250 from 1%
  c.lr_decay_steps = 250000;
  return c;
}
}  // namespace

TEST(LrSchedule, SpecValues) {
  const LrSchedule lr(release());
  EXPECT_NEAR(lr(0), 5e-6, 1e-12);
  EXPECT_NEAR(lr(625), 3.54e-4, 0.01e-4);
  EXPECT_NEAR(lr(1250), 4.96e-4, 0.01e-4);
  EXPECT_NEAR(lr(125000), 2.24e-4, 0.01e-4);
  EXPECT_NEAR(lr(250000), 1e-4, 1e-12);
  EXPECT_NEAR(lr(400000), 1e-4, 1e-12);  // constant afterwards
}

TEST(LrSchedule, ClosedFormAndMonotoneDecay) {
  const LrSchedule lr(release());
  // hand-computed: s = 625 -> warm = 0.01 + 0.99 sin(pi/4); decay = 5e-4 * 0.2^(625/250000)
  const double expect = (0.01 + 0.99 * std::sin(M_PI / 4)) * 5e-4 * std::pow(0.2, 625.0 / 250000.0);
  EXPECT_NEAR(lr(625), expect, 1e-15);
  for (int64_t s = 1250; s < 250000; s += 997) EXPECT_GT(lr(s), lr(s + 997) - 1e-18);
}

TEST(LrSchedule, DecayOverTheStepBudgetWhenZero) {
  TrainConfig c;
  c.steps = 1000;
  c.lr_decay_steps = 0;
  c.lr_warmup_steps = 0;
  const LrSchedule lr(c);
  EXPECT_NEAR(lr(0), c.lr_init, 1e-15);
  EXPECT_NEAR(lr(500), std::sqrt(c.lr_init * c.lr_final), 1e-12);  // geometric midpoint
  EXPECT_NEAR(lr(1000), c.lr_final, 1e-15);
}

// With a time budget the decay runs at the budget's pace while the warm-up still counts optimiser
// steps: at step 50 of a 100-step warm-up, halfway through the decay, the rate is the warm-up factor
// of step 50 times the decay at its midpoint.
TEST(LrSchedule, WarmUpCountsOptimiserStepsWhileTheDecayFollowsTheBudget) {
  TrainConfig c;
  c.steps = 100000;
  c.lr_decay_steps = 0;
  c.lr_warmup_steps = 100;
  c.lr_warmup_mult = 0.01;
  const LrSchedule lr(c);
  const double warm50 = 0.01 + 0.99 * std::sin(0.5 * M_PI * 0.5);
  EXPECT_NEAR(lr(50, 50000), warm50 * std::sqrt(c.lr_init * c.lr_final), 1e-15);
  EXPECT_NEAR(lr(0, 99000), 0.01 * c.lr_init * std::pow(c.lr_final / c.lr_init, 0.99), 1e-15);
  EXPECT_NEAR(lr(200, 100000), c.lr_final, 1e-15);
  EXPECT_EQ(lr(70, 70), lr(70));  // without a budget both positions are the step
}
