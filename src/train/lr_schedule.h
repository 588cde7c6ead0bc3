#pragma once
// Learning-rate schedule of the release (docs/MODEL.md, section 8): a sine warm-up from lr_warmup_mult of the
// base rate over lr_warmup_steps, times a log-linear decay from lr_init to lr_final over
// lr_decay_steps (constant lr_final afterwards). Step s counts optimiser steps from 0.
// With a time budget the decay follows where the schedule stands (the share of the budget spent,
// in steps), while the warm-up still counts optimiser steps: a warm-up of 500 steps lasts 500 steps
// whatever the budget.
#include <cstdint>

#include "train/train_config.h"

namespace ablenerf {

class LrSchedule {
 public:
  explicit LrSchedule(const TrainConfig& c);
  double operator()(int64_t step) const { return (*this)(step, step); }
  // Warm-up at optimiser step `step`, decay at schedule position `decay_step` (>= step).
  double operator()(int64_t step, int64_t decay_step) const;

 private:
  double init_, final_, warmup_mult_;
  int64_t warmup_steps_, decay_steps_;
};

}  // namespace ablenerf
