#pragma once
// Trainer's state (train/trainer.h), shared by the files that implement it: trainer_setup.cpp (the
// run folder, the dataset, resuming, building the model and optimiser) and trainer.cpp (the steps
// and run()'s hooks). Private to src/train.
#include <chrono>
#include <cmath>
#include <memory>
#include <optional>
#include <string>

#include "data/dataset.h"
#include "model/able_nerf.h"
#include "run/run_folder.h"
#include "train/adam.h"
#include "train/checkpoint.h"
#include "train/cuda_step.h"
#include "train/lr_schedule.h"
#include "train/ray_batch.h"
#include "train/trainer.h"
#include "util/progress.h"
#include "data/data_config.h"

namespace ablenerf {

namespace trainer_detail {
// Eager steps on the capture stream before the CUDA graph is captured.
inline constexpr int64_t kGraphWarmupSteps = 3;
// Seconds between progress lines when stderr is not a terminal.
inline constexpr double kProgressIntervalS = 15.0;
// Seconds over which the rays/s figure of the progress line is averaged.
inline constexpr double kRateWindowS = 0.5;
// A step's figures on the device: loss, fine MSE, found-inf flag, the loss's terms, then (with the
// error map) each ray's squared error.
inline constexpr int64_t kFigureFound = 2;
inline constexpr int64_t kFigureTerms = 3;
inline constexpr int64_t kFigureRays = kFigureTerms + kLossTermCount;
}  // namespace trainer_detail

struct Trainer::State {
  int rank = 0, world = 1;
  bool leader = true;
  RunFolder run;  // empty dir: no run folder (bench)
  std::optional<Dataset> ds;
  // Where samples lie: the dataset's scene (near/far, bounded or unbounded), else the config's.
  double near = 2, far = 6;
  SceneKind scene = SceneKind::Bounded;
  std::string held_out;  // split for the periodic PSNR ("" = none)
  AbleNerf model{nullptr};
  std::unique_ptr<Adam> adam;
  std::unique_ptr<RaySampler> sampler;
  std::optional<LrSchedule> schedule;
  TrainState state;
  int64_t local_rays = 0, micro = 0;
  // train.distortion_start's ramp (train/regularisers.h): the share of the distortion weight this
  // step carries, a 0-d tensor on the training device that the step (and a captured graph) reads;
  // undefined when the term is on throughout. `distortion_share` is its value on the host.
  torch::Tensor distortion_scale;
  double distortion_share = -1;
  // Device form.
  std::unique_ptr<CudaStep> cuda;
  torch::Tensor indices_dev;      // this step's ray indices on the device (the graph's input)
  torch::Tensor figures_dev;      // the step's figures (trainer_detail::kFigure*; the graph's output)
  double pending_lr = NAN;        // lr of the step whose figures are in flight
  torch::Tensor pending_indices;  // its ray indices, until its errors reach the error map
  StepReport last;
  // Time: seconds trained before this invocation, the clock of this one, the agreed elapsed.
  double elapsed_before = 0;
  std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now();
  double agreed_elapsed = 0;
  // Hooks' bookkeeping.
  int64_t bad_in_a_row = 0, steps_this_run = 0;
  double loss_acc = 0, mse_fine_acc = 0;
  std::array<double, kLossTermCount> terms_acc{};
  int64_t acc_steps = 0, rays_since_log = 0;
  std::chrono::steady_clock::time_point rate_clock = std::chrono::steady_clock::now();
  double rays_per_s = 0;
  std::optional<Progress> progress;

  double local_elapsed() const {
    return elapsed_before + std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }
};

}  // namespace ablenerf
