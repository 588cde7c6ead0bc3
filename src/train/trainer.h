#pragma once
// `ablenerf train`: the training loop of docs/MODEL.md, section 8 on one process or a data-parallel group,
// as a class of small steps (setup, step, and the hooks of run()).
//
// One optimiser step (Trainer::step) is the one training-step implementation of the project:
// the CLI's training loop and `ablenerf bench` both call it. It has two forms over the same work:
//  - host form (the CPU, or several processes): draw rays, forward and backward over
//    micro-batches, all-reduce gradients between processes, a finite check, the Adam update;
//    the step's loss is known when step() returns;
//  - device form (one CUDA process, LibTorch >= 2): the same work queued on the GPU without any
//    host synchronisation (ray indices drawn on the host and uploaded asynchronously, the rays
//    gathered on the device, the finite check and a fused Adam on the device), captured once as a
//    CUDA graph and replayed (train.graph = true), or run eagerly; the step's figures are read one
//    step late.
#include <torch/torch.h>

#include <array>
#include <cmath>
#include <functional>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "data/dataset.h"
#include "model/able_nerf.h"
#include "train/grad_accumulation.h"
#include "util/config.h"

namespace ablenerf {

class Adam;         // train/adam.h
class Distributed;  // train/distributed.h

class Trainer;

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
  bool quiet = false;           // no progress line (tests)
  Distributed* dist = nullptr;  // null = one process
  // Called by run() after every step and its hooks, on the training thread, between steps (the
  // model is not being updated): the live viewer copies weights there, pauses by blocking, and
  // asks for checkpoints (`train --view`). Empty: nothing.
  std::function<void(Trainer&)> between_steps;
};

// The outcome of a call to Trainer::run().
enum class TrainResult { Finished, Interrupted, StoppedEarly };

// Thrown when too many consecutive steps had a non-finite loss or gradient: the run stops and
// the last checkpoint (written before the bad steps) is left as it was.
class TrainingDiverged : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Exit code of the CLI for TrainingDiverged.
constexpr int kExitDiverged = 3;

// What a step reports. In the device form the figures are those of the previous step (read one
// step late): `step` says which step they belong to, -1 when there is none yet.
struct StepReport {
  int64_t step = -1;  // 1-based index of the optimiser step these figures belong to
  double loss = NAN;
  double mse_fine = NAN;
  std::array<double, kLossTermCount> terms{};  // the loss's terms (train/grad_accumulation.h, LossTerm)
  bool finite = true;                          // false: the update of that step was skipped
  double lr = NAN;
};

class Trainer {
 public:
  Trainer(Config config, TrainOptions opts);
  ~Trainer();
  Trainer(const Trainer&) = delete;
  Trainer& operator=(const Trainer&) = delete;

  // Opens or creates the run folder, loads the data, builds the model and optimiser, resumes
  // from the checkpoint with opts.resume.
  void setup();
  // The same on an in-memory training split, with no run folder (nothing is read or written):
  // what `ablenerf bench` measures.
  void setup(const Split& train, const Intrinsics& k);

  // One optimiser step on one global batch: draw rays, forward, loss, backward over micro-batches,
  // all-reduce (several processes), finite check, update. No logging and no I/O.
  StepReport step();
  // Waits for the device work in flight and returns the figures of the last step (device form;
  // the host form returns the last report again).
  StepReport flush();

  // Steps until the schedule (or its time budget) is done, with the hooks: progress and log
  // lines, held-out PSNR, checkpoints, time limits, Ctrl-C. Returns how it ended.
  TrainResult run();

  AbleNerf& model();
  // The optimiser and its state (tests read the moments of a step).
  Adam& optimiser();
  int64_t steps_done() const;
  // Writes the checkpoint and weights now (what run() does at its checkpoints).
  void checkpoint_now();
  bool device_form() const;
  bool graph_captured() const;

 private:
  struct State;
  void build(const Split& train, const Intrinsics& k);
  double schedule_fraction() const;
  int64_t schedule_step() const;
  // `all`: the step's global ray indices; `indices`: this rank's slice of them.
  StepReport host_step(const torch::Tensor& all, const torch::Tensor& indices, double lr);
  StepReport device_step(const torch::Tensor& all, const torch::Tensor& indices, double lr);
  // Feeds a finished step's figures [loss, mse_fine, found_inf, ray_se...] to the error map.
  void observe_pending(const std::vector<double>& figures);
  void device_body();
  // Hooks of run().
  void save();
  void log_step(const StepReport& r);
  void held_out_check();
  void check_divergence(const StepReport& r);
  // The passes per training pixel the run made, in the log and (unless quiet) one line, with
  // coverage_advice's line when they were few.
  void report_coverage();

  Config config_;
  TrainOptions opts_;
  std::unique_ptr<State> s_;
};

// Trainer(config, opts), setup(), run().
TrainResult train(const Config& config, const TrainOptions& opts);

// How often a run drew each training pixel on average: steps x rays per step / training pixels.
double passes_per_pixel(int64_t steps, int64_t rays_per_step, int64_t pixels);
// Below this many passes fine detail is still being learnt when a run ends.
inline constexpr double kFewPasses = 2.0;
// Images are not advised smaller than this many pixels on their short side.
inline constexpr int kSmallestAdvisedSide = 64;
// For a run that made `passes` passes at data.downscale `downscale` within `budget_s` seconds
// (0 = a run of steps) on images `short_side` pixels on their short side: "" from kFewPasses on,
// else one line saying what reaches kFewPasses: a budget that many times longer, or images reduced
// by the factor that divides the pixels by it (when they keep kSmallestAdvisedSide pixels).
std::string coverage_advice(double passes, int downscale, double budget_s, int short_side);

// Installs SIGINT/SIGTERM handlers that ask the training loop to checkpoint and stop.
void install_interrupt_handlers();
// Whether such a signal has arrived (a paused live run stops waiting then).
bool interrupt_requested();

// The views of a held-out split of `size` images that the training-time check renders: `count`
// of them spread evenly over the split (index floor(i * size / count)), so that on an orbit such as
// Blender's test path the curve sees every side of the scene, not the first few neighbouring views.
std::vector<int64_t> held_out_views(int64_t size, int64_t count);

}  // namespace ablenerf
