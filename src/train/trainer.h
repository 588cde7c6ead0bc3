#pragma once
// `ablenerf train`: the training loop of spec section 8 on one process or a data-parallel group.
#include <torch/torch.h>

#include <cstdint>
#include <string>

#include "util/config.h"

namespace ablenerf {

class Distributed;  // train/distributed.h

struct TrainOptions {
  std::string data_dir;  // dataset folder (with --resume: may be empty, then run.json's)
  std::string out_dir;   // run folder
  bool resume = false;
  torch::Device device = torch::kCPU;
  // Stop (with a checkpoint) after this many steps of this invocation; < 0 = run to the budget.
  // Lets tests and schedulers split a run into pieces.
  int64_t max_steps_this_run = -1;
  // Stop (with a checkpoint) once this invocation has trained this many seconds; <= 0 = no limit.
  // The schedule stays the one of train.steps: this is a wall-clock guard, not a budget.
  double time_limit_s = 0;
  bool quiet = false;  // no progress line (tests)
  Distributed* dist = nullptr;  // null = one process
};

// The outcome of a call to train().
enum class TrainResult { Finished, Interrupted, StoppedEarly };

// Thrown when too many consecutive steps had a non-finite loss or gradient: the run stops and
// the last checkpoint (written before the bad steps) is left as it was.
class TrainingDiverged : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Exit code of the CLI for TrainingDiverged.
constexpr int kExitDiverged = 3;

TrainResult train(const Config& config, const TrainOptions& opts);

// Installs SIGINT/SIGTERM handlers that ask the training loop to checkpoint and stop.
void install_interrupt_handlers();

}  // namespace ablenerf
