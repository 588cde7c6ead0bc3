#include "train/trainer.h"

#include <atomic>
#include <cmath>
#include <csignal>
#include <filesystem>
#include <iostream>
#include <nlohmann/json.hpp>

#include "data/dataset.h"
#include "data/load_options.h"
#include "eval/metrics.h"
#include "eval/renderer.h"
#include "run/run_folder.h"
#include "run/run_log.h"
#include "model/able_nerf.h"
#include "model/compute.h"
#include "train/checkpoint.h"
#include "train/distributed.h"
#include "train/grad_accumulation.h"
#include "train/lr_schedule.h"
#include "train/ray_batch.h"
#include "util/errors.h"
#include "util/fs.h"
#include "util/progress.h"

namespace fs = std::filesystem;

namespace ablenerf {

namespace {

std::atomic<bool> g_interrupt{false};

void on_signal(int) { g_interrupt.store(true); }

double mse_to_psnr(double mse) { return -10.0 * std::log10(std::max(mse, 1e-12)); }

// Mean PSNR of the fine colour on the first `views` images of the held-out split.
double held_out_psnr(AbleNerf& model, const Split& split, const Intrinsics& k, const Config& c, int64_t views,
                     const torch::Device& device) {
  const bool was_training = model->is_training();
  model->eval();
  double sum = 0;
  const int64_t n = std::min<int64_t>(views, split.size());
  for (int64_t i = 0; i < n; ++i) {
    RenderResult r = render_image(model, split.c2w[i], k, c.data.near, c.data.far, c.eval.chunk, {}, device);
    sum += psnr(r.rgb.cpu(), split.images[i]);
  }
  if (was_training) model->train();
  return n > 0 ? sum / static_cast<double>(n) : NAN;
}

// True when every gradient is finite.
bool gradients_finite(AbleNerf& model) {
  std::vector<torch::Tensor> norms;
  for (const auto& p : model->parameters())
    if (p.grad().defined()) norms.push_back(p.grad().abs().max());
  if (norms.empty()) return true;
  return torch::stack(norms).isfinite().all().item<bool>();
}

}  // namespace

void install_interrupt_handlers() {
  std::signal(SIGINT, on_signal);
  std::signal(SIGTERM, on_signal);
}

TrainResult train(const Config& config, const TrainOptions& opts) {
  const bool single = opts.dist == nullptr;
  const int rank = single ? 0 : opts.dist->rank();
  const int world = single ? 1 : opts.dist->world_size();
  const bool leader = rank == 0;
  const TrainConfig& tc = config.train;

  // Run folder: new, or the one being resumed (whose config must match).
  RunFolder run;
  const bool have_ckpt = fs::exists(fs::path(opts.out_dir) / "checkpoint.pt");
  if (opts.resume && have_ckpt) {
    run = RunFolder::open(opts.out_dir);
    if (!opts.data_dir.empty()) run.data_dir = opts.data_dir;
  } else {
    if (!opts.resume && have_ckpt)
      throw InputError(opts.out_dir, "checkpoint.pt",
                       "the run folder already holds a run (use --resume to continue it, or another --out)");
    if (opts.data_dir.empty()) throw InputError("train", "--data", "required");
    if (leader) run = RunFolder::create(opts.out_dir, config, opts.data_dir);
    else run.dir = opts.out_dir, run.config = config, run.data_dir = opts.data_dir;
  }
  if (run.data_dir.empty()) throw InputError(run.path("run.json"), "data", "missing: give --data");
  if (leader) run.remove_stale_temporaries();

  // Data: the training split, and a held-out split for the periodic PSNR (val, else test).
  std::vector<std::string> want{"train"};
  const auto present = available_splits(run.data_dir);
  std::string held_out;
  for (const char* s : {"val", "test"})
    if (held_out.empty() && std::find(present.begin(), present.end(), s) != present.end()) held_out = s;
  if (tc.eval_every > 0 && leader && !held_out.empty()) want.push_back(held_out);
  const Dataset ds = Dataset::load(run.data_dir, load_options_for(config, want));
  if (!ds.has("train")) throw InputError(run.data_dir, "transforms_train.json", "the dataset has no train split");

  torch::manual_seed(static_cast<uint64_t>(tc.seed));
  AbleNerf model(config.model);
  model->to(opts.device);
  model->set_precision(apply_compute_config(config.compute, opts.device, config.source));
  model->train();
  torch::optim::Adam optim(model->parameters(),
                           torch::optim::AdamOptions(tc.lr_init).betas({0.9, 0.999}).eps(1e-8).weight_decay(0));
  RaySampler sampler(ds.split("train"), ds.intrinsics, opts.device, static_cast<uint64_t>(tc.seed));
  const LrSchedule schedule(tc);

  TrainState state;
  if (opts.resume && have_ckpt) {
    state = load_checkpoint(run.checkpoint_path(), config, model, optim);
    sampler.set_rng_state(state.rng_state);
    if (leader) std::cerr << "train: resumed " << run.checkpoint_path() << " at step " << state.step << "\n";
  }
  if (!single) opts.dist->broadcast_parameters(model);  // every rank starts from rank 0's weights

  auto save = [&]() {
    if (!leader) return;
    state.rng_state = sampler.rng_state();
    save_weights(model, run.weights_path());
    save_checkpoint(run.checkpoint_path(), config, model, optim, state);
  };

  const int64_t local_rays = tc.rays_per_step * (rank + 1) / world - tc.rays_per_step * rank / world;
  const int64_t micro = std::min<int64_t>(tc.micro_batch, std::max<int64_t>(local_rays, 1));
  Progress progress("train", tc.steps, 15.0);
  const double elapsed_before = state.elapsed_seconds;
  int64_t bad_in_a_row = 0, steps_this_run = 0;
  double loss_acc = 0, mse_fine_acc = 0;
  int64_t acc_steps = 0, rays_since_log = 0;
  auto log_clock = std::chrono::steady_clock::now();
  double rays_per_s = 0;

  if (!single && tc.time_budget_s > 0)
    throw InputError(config.source, "train.time_budget_s",
                     "not supported with several processes (ranks would disagree on the schedule)");
  // Where the schedule stands: the step, or with a time budget the share of it already spent if
  // that is further along (elapsed time counts across resumes).
  const auto schedule_step = [&]() -> int64_t {
    if (tc.time_budget_s <= 0) return state.step;
    const double spent = (elapsed_before + progress.elapsed_seconds()) / tc.time_budget_s;
    return std::max<int64_t>(state.step, static_cast<int64_t>(spent * static_cast<double>(tc.steps)));
  };

  while (state.step < tc.steps) {
    if (schedule_step() >= tc.steps) {
      if (leader && !opts.quiet)
        std::cerr << "\ntrain: time budget of " << tc.time_budget_s << " s spent at step " << state.step << "\n";
      break;
    }
    if (g_interrupt.load()) {
      save();
      if (leader) std::cerr << "\ntrain: interrupted; checkpoint saved at step " << state.step << "\n";
      return TrainResult::Interrupted;
    }
    const bool step_limit = opts.max_steps_this_run >= 0 && steps_this_run >= opts.max_steps_this_run;
    const bool time_limit = opts.time_limit_s > 0 && progress.elapsed_seconds() >= opts.time_limit_s;
    if (step_limit || time_limit) {
      save();
      if (time_limit && leader && !opts.quiet)
        std::cerr << "\ntrain: time limit reached at step " << state.step << "; checkpoint saved (--resume continues)\n";
      return TrainResult::StoppedEarly;
    }
    const double lr = schedule(schedule_step());
    for (auto& g : optim.param_groups()) static_cast<torch::optim::AdamOptions&>(g.options()).lr(lr);

    RayBatch batch = sampler.next(tc.rays_per_step, rank, world);
    optim.zero_grad();
    const StepSums sums =
        accumulate_gradients(model, batch, micro, tc, tc.rays_per_step, config.data.near, config.data.far);
    double step_loss = sums.loss, step_mse_fine = sums.mse_fine;
    if (!single) {
      double stats[2] = {step_loss, step_mse_fine};
      opts.dist->all_reduce_gradients(model, stats, 2);
      step_loss = stats[0];
      step_mse_fine = stats[1];
    }
    const bool finite = std::isfinite(step_loss) && gradients_finite(model);
    if (!finite) {
      ++bad_in_a_row;
      optim.zero_grad();
      if (leader)
        std::cerr << "\ntrain: step " << state.step << ": non-finite loss or gradient, step skipped (" << bad_in_a_row
                  << " in a row)\n";
      if (bad_in_a_row >= tc.max_bad_steps)
        throw TrainingDiverged("training diverged: " + std::to_string(bad_in_a_row) +
                               " consecutive non-finite steps at step " + std::to_string(state.step) +
                               "; the last checkpoint (" + run.checkpoint_path() +
                               ") is intact. Lower train.lr_init or check the data.");
      state.step++;  // keep the schedule and the ray stream aligned with an uninterrupted run
      continue;
    }
    bad_in_a_row = 0;
    optim.step();
    state.step++;
    steps_this_run++;
    loss_acc += step_loss;
    mse_fine_acc += step_mse_fine;
    acc_steps++;
    rays_since_log += tc.rays_per_step;

    const double now_elapsed = elapsed_before + progress.elapsed_seconds();
    state.elapsed_seconds = now_elapsed;
    if (leader) {
      const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - log_clock).count();
      if (secs > 0.5) {
        rays_per_s = static_cast<double>(rays_since_log) / secs;
        rays_since_log = 0;
        log_clock = std::chrono::steady_clock::now();
      }
      char fields[160];
      std::snprintf(fields, sizeof fields, "loss %.5f psnr %.2f lr %.2e %.0f rays/s", step_loss,
                    mse_to_psnr(step_mse_fine), lr, rays_per_s);
      if (!opts.quiet) progress.update(state.step, fields);
      if (state.step % tc.log_every == 0 || state.step == tc.steps) {
        nlohmann::json j{{"type", "train"},
                         {"step", state.step},
                         {"loss", loss_acc / static_cast<double>(acc_steps)},
                         {"psnr", mse_to_psnr(mse_fine_acc / static_cast<double>(acc_steps))},
                         {"lr", lr},
                         {"rays_per_s", rays_per_s},
                         {"elapsed_s", now_elapsed}};
        append_run_log(run.log_path(), j);
        loss_acc = mse_fine_acc = 0;
        acc_steps = 0;
      }
      if (tc.eval_every > 0 && !held_out.empty() && (state.step % tc.eval_every == 0 || state.step == tc.steps)) {
        const double p = held_out_psnr(model, ds.split(held_out), ds.intrinsics, config, tc.eval_views, opts.device);
        append_run_log(run.log_path(), {{"type", "eval"}, {"step", state.step}, {"psnr", p}, {"views", tc.eval_views},
                                  {"split", held_out}, {"elapsed_s", now_elapsed}});
        if (!opts.quiet) std::cerr << (progress.elapsed_seconds() > 0 ? "\n" : "") << "train: step " << state.step
                                   << " held-out " << held_out << " PSNR " << p << " dB\n";
      }
    }
    if (tc.ckpt_every > 0 && state.step % tc.ckpt_every == 0 && state.step < tc.steps) save();
  }
  save();
  if (leader && !opts.quiet) progress.finish("done");
  return TrainResult::Finished;
}

}  // namespace ablenerf
