#include "train/lr_schedule.h"
#include "train/train_config.h"

#include <algorithm>
#include <cmath>

namespace ablenerf {

LrSchedule::LrSchedule(const TrainConfig& c)
    : init_(c.lr_init),
      final_(c.lr_final),
      warmup_mult_(c.lr_warmup_mult),
      warmup_steps_(c.lr_warmup_steps),
      decay_steps_(c.lr_decay_steps > 0 ? c.lr_decay_steps : c.steps) {}

double LrSchedule::operator()(int64_t step, int64_t decay_step) const {
  const double s = static_cast<double>(step);
  double warm = 1.0;
  if (warmup_steps_ > 0) {
    const double x = std::clamp(s / static_cast<double>(warmup_steps_), 0.0, 1.0);
    warm = warmup_mult_ + (1.0 - warmup_mult_) * std::sin(0.5 * M_PI * x);
  }
  const double d = static_cast<double>(decay_step);
  const double tau = decay_steps_ > 0 ? std::clamp(d / static_cast<double>(decay_steps_), 0.0, 1.0) : 1.0;
  return warm * std::exp((1.0 - tau) * std::log(init_) + tau * std::log(final_));
}

}  // namespace ablenerf
