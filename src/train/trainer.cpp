#include "train/trainer.h"

#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <filesystem>
#include <optional>
#include <sstream>
#include <nlohmann/json.hpp>

#include "data/data_config.h"
#include "data/load_options.h"
#include "eval/metrics.h"
#include "eval/renderer.h"
#include "kernels/cpu_parallel.h"
#include "model/able_nerf.h"
#include "model/compute.h"
#include "run/run_folder.h"
#include "run/run_log.h"
#include "train/adam.h"
#include "train/checkpoint.h"
#include "train/cuda_step.h"
#include "train/distributed.h"
#include "train/grad_accumulation.h"
#include "model/camera_refine.h"
#include "train/lr_schedule.h"
#include "train/ray_batch.h"
#include "train/regularisers.h"
#include "train/trainer_state.h"
#include "util/errors.h"
#include "util/fs.h"
#include "util/log.h"
#include "util/progress.h"
#include "eval/eval_config.h"
#include "train/train_config.h"

namespace fs = std::filesystem;

namespace ablenerf {

namespace {

std::atomic<bool> g_interrupt{false};

void on_signal(int) { g_interrupt.store(true); }

}  // namespace

using namespace trainer_detail;

bool interrupt_requested() { return g_interrupt.load(); }

void install_interrupt_handlers() {
  std::signal(SIGINT, on_signal);
  std::signal(SIGTERM, on_signal);
}

Trainer::Trainer(Config config, TrainOptions opts)
    : config_(std::move(config)), opts_(std::move(opts)), s_(std::make_unique<State>()) {
  // A CUDA device always with its index (LibTorch 2.x refuses index -1 in places).
  if (opts_.device.is_cuda() && !opts_.device.has_index()) opts_.device = torch::Device(torch::kCUDA, 0);
  s_->rank = opts_.dist ? opts_.dist->rank() : 0;
  s_->world = opts_.dist ? opts_.dist->world_size() : 1;
  s_->leader = s_->rank == 0;
}

Trainer::~Trainer() = default;

AbleNerf& Trainer::model() { return s_->model; }
Adam& Trainer::optimiser() { return *s_->adam; }
int64_t Trainer::steps_done() const { return s_->state.step; }
bool Trainer::device_form() const { return s_->cuda != nullptr; }
bool Trainer::graph_captured() const { return s_->cuda && s_->cuda->captured(); }

// Where the schedule stands in [0, 1]: the share of steps done or, with a time budget, the share
// of it already spent if that is further along (elapsed time counts across resumes).
double Trainer::schedule_fraction() const {
  const TrainConfig& tc = config_.get<TrainConfig>();
  const double by_steps = tc.steps > 0 ? static_cast<double>(s_->state.step) / static_cast<double>(tc.steps) : 1.0;
  if (tc.time_budget_s <= 0) return by_steps;
  return std::max(by_steps, s_->agreed_elapsed / tc.time_budget_s);
}

int64_t Trainer::schedule_step() const {
  const auto by_time =
      static_cast<int64_t>(schedule_fraction() * static_cast<double>(config_.get<TrainConfig>().steps));
  return std::max<int64_t>(s_->state.step, by_time);
}

StepReport Trainer::step() {
  auto& s = *s_;
  if (!s.model) throw std::logic_error("Trainer::step before setup");
  // The elapsed time the schedule follows: with several processes the group's mean, agreed in the
  // step's all-reduce (host form), so that every rank takes the same decisions.
  if (!opts_.dist) s.agreed_elapsed = s.local_elapsed();
  const double lr = (*s.schedule)(s.state.step, schedule_step());
  const TrainConfig& tc = config_.get<TrainConfig>();
  // Every rank draws the same global batch from one identically seeded stream and keeps its slice;
  // its first rays are coarse pixels while train.coarse_pixel_share asks for them.
  const int64_t coarse =
      coarse_pixel_rays(tc.rays_per_step, tc.coarse_pixel_share, tc.coarse_pixel_until, schedule_fraction());
  const auto all = s.sampler->draw(tc.rays_per_step, coarse);
  const int64_t begin = tc.rays_per_step * s.rank / s.world;
  const auto indices = all.slice(0, begin, begin + s.local_rays);
  // BARF's coarse-to-fine window while the cameras are refined (before the step: a captured graph
  // reads the window's tensor, which this updates in place).
  if (tc.camera_refine && tc.camera_refine_c2f_end > 0)
    s.model->set_frequency_window(coarse_to_fine_alpha(schedule_fraction(), tc.camera_refine_c2f_start,
                                                       tc.camera_refine_c2f_end, s.model->ipe_bands()));
  if (s.distortion_scale.defined()) {
    // Written only when it changes: on a GPU a copy from the host is queued on the step's stream.
    const double share = distortion_ramp(tc.distortion_start, schedule_fraction(), tc.distortion_ramp);
    if (share != s.distortion_share) s.distortion_scale.fill_(share);
    s.distortion_share = share;
  }
  StepReport r = s.cuda ? device_step(all, indices, lr) : host_step(all, indices, lr);
  s.state.step++;
  s.state.elapsed_seconds = s.local_elapsed();
  return r;
}

StepReport Trainer::host_step(const torch::Tensor& all, const torch::Tensor& indices, double lr) {
  auto& s = *s_;
  const TrainConfig& tc = config_.get<TrainConfig>();
  s.adam->set_lr(lr);
  s.adam->clear_grads();
  // With the CPU ray split, the step's own LibTorch loops (over the grid's table: gradients summed,
  // decayed) run on this thread alone: their OpenMP team's idle member would spin into the split's
  // slices (docs/benchmarks/history.md, "The step's own loops on one thread": +14% steps in 15 minutes).
  std::optional<SerialIntraOp> serial;
  if (s.model->cpu_ray_workers(s.micro, /*draws_randomness=*/false) > 1) serial.emplace();
  const RayBatch batch = s.sampler->gather(indices);
  // The CPU grid tables' gradients formed inside Adam's update, never stored (Adam::TableStep),
  // unless an all-reduce must add them up first.
  const bool tables_in_update = !opts_.dist && s.adam->host_loops();
  StepSums sums = accumulate_gradients(s.model, batch, s.micro, tc, tc.rays_per_step, s.near, s.far, s.distortion_scale,
                                       tables_in_update);
  StepReport r;
  r.step = s.state.step + 1;
  r.lr = lr;
  r.loss = sums.loss.item<double>();
  r.mse_fine = sums.mse_fine.item<double>();
  const torch::Tensor terms = sums.terms.to(torch::kCPU, torch::kDouble).contiguous();
  std::copy(terms.data_ptr<double>(), terms.data_ptr<double>() + kLossTermCount, r.terms.begin());
  // The error map needs every rank's per-ray errors: they travel in the all-reduce, each rank
  // filling its slice of the global batch with zeros elsewhere.
  const bool guided = s.sampler->error_guided();
  torch::Tensor ray_se = guided ? sums.ray_se.to(torch::kCPU, torch::kDouble) : torch::Tensor();
  if (opts_.dist) {
    // [loss, mse_fine, elapsed / world, terms..., ray_se...]
    constexpr int64_t kRays = 3 + kLossTermCount;
    std::vector<double> stats(kRays + (guided ? all.size(0) : 0), 0.0);
    stats[0] = r.loss, stats[1] = r.mse_fine, stats[2] = s.local_elapsed() / static_cast<double>(s.world);
    std::copy(r.terms.begin(), r.terms.end(), stats.begin() + 3);
    if (guided) {
      const int64_t begin = tc.rays_per_step * s.rank / s.world;
      std::copy(ray_se.data_ptr<double>(), ray_se.data_ptr<double>() + ray_se.size(0), stats.begin() + kRays + begin);
    }
    opts_.dist->all_reduce_gradients(s.model, stats.data(), static_cast<int>(stats.size()));
    r.loss = stats[0];
    r.mse_fine = stats[1];
    s.agreed_elapsed = stats[2];
    std::copy(stats.begin() + 3, stats.begin() + kRays, r.terms.begin());
    if (guided) ray_se = torch::tensor(std::vector<double>(stats.begin() + kRays, stats.end()), torch::kDouble);
  }
  // The tables' finite check made while gathering them holds unless an all-reduce changed them.
  r.finite = s.adam->step_host(r.loss, opts_.dist ? std::vector<torch::Tensor>() : sums.finite_tables,
                               tables_in_update ? &sums.tables : nullptr);
  // Their decay's value comes out of that update.
  for (const auto& t : sums.tables) {
    r.loss += t.value;
    r.terms[kTermGridDecay] += t.value;
  }
  if (guided && r.finite) s.sampler->observe(all, ray_se);
  if (!r.finite) s.adam->clear_grads();
  s.last = r;
  return r;
}

// The device work of one step, in stream order and without a host synchronisation: what the
// CUDA graph captures.
void Trainer::device_body() {
  auto& s = *s_;
  const TrainConfig& tc = config_.get<TrainConfig>();
  const RayBatch batch = s.sampler->gather(s.indices_dev);
  StepSums sums;
  {
    // One autocast scope around every micro-batch: each weight is cast to bf16 once per step.
    const AutocastScope autocast(s.model->compute().precision, opts_.device);
    sums = accumulate_gradients(s.model, batch, s.micro, tc, tc.rays_per_step, s.near, s.far, s.distortion_scale);
  }
  s.adam->step_device(sums.loss);
  torch::NoGradGuard no_grad;
  std::vector<torch::Tensor> figures{sums.loss.reshape({1}).to(torch::kFloat),
                                     sums.mse_fine.reshape({1}).to(torch::kFloat), s.adam->found_inf().reshape({1}),
                                     sums.terms.to(torch::kFloat)};
  if (s.sampler->error_guided()) figures.push_back(sums.ray_se.reshape({-1}).to(torch::kFloat));
  s.figures_dev.copy_(torch::cat(figures));
}

namespace {

// The report of a step from its figures as the device wrote them (trainer_detail::kFigure*).
StepReport figures_report(const std::vector<double>& f, int64_t step, double lr) {
  StepReport r;
  r.step = step;
  r.loss = f[0];
  r.mse_fine = f[1];
  r.finite = f[kFigureFound] == 0.0;
  std::copy(f.begin() + kFigureTerms, f.begin() + kFigureRays, r.terms.begin());
  r.lr = lr;
  return r;
}

}  // namespace

void Trainer::observe_pending(const std::vector<double>& figures) {
  auto& s = *s_;
  if (!s.pending_indices.defined()) return;  // already fed (flush, then the next step)
  if (s.sampler->error_guided() && figures[kFigureFound] == 0.0) {
    const auto n = static_cast<int64_t>(figures.size()) - kFigureRays;
    s.sampler->observe(
        s.pending_indices,
        torch::tensor(std::vector<double>(figures.begin() + kFigureRays, figures.end()), torch::kDouble).reshape({n}));
  }
  s.pending_indices = torch::Tensor();
}

// On the device the step's errors reach the host one step later, so the error map draws a step's
// rays from the errors of the step before the previous one.
StepReport Trainer::device_step(const torch::Tensor& all, const torch::Tensor& indices, double lr) {
  auto& s = *s_;
  s.cuda->upload(indices, s.indices_dev);
  s.adam->set_lr(lr);
  s.cuda->run([this] { device_body(); }, [this] { s_->adam->clear_grads(); });
  // The previous step's figures (their copy was queued after that step), then this step's.
  StepReport r;
  if (auto f = s.cuda->take()) {
    observe_pending(*f);
    r = figures_report(*f, s.state.step, s.pending_lr);  // the previous step, 1-based
    s.last = r;
  }
  s.cuda->queue(s.figures_dev);
  s.pending_lr = lr;
  s.pending_indices = all;
  return r;
}

StepReport Trainer::flush() {
  auto& s = *s_;
  if (!s.cuda) return s.last;
  if (auto f = s.cuda->drain()) {
    observe_pending(*f);
    s.last = figures_report(*f, s.state.step, s.pending_lr);
  }
  return s.last;
}

void Trainer::save() {
  auto& s = *s_;
  if (!s.leader || s.run.dir.empty()) return;
  flush();
  s.adam->to_checkpoint();
  s.state.rng_state = s.sampler->rng_state();
  s.state.error_map = s.sampler->map_state();
  save_weights(s.model, s.run.weights_path());
  save_checkpoint(s.run.checkpoint_path(), config_, s.model, s.adam->optim(), s.state);
}

void Trainer::check_divergence(const StepReport& r) {
  auto& s = *s_;
  if (r.step < 0) return;
  if (r.finite) {
    s.bad_in_a_row = 0;
    return;
  }
  ++s.bad_in_a_row;
  if (s.leader)
    log_warn("train: step " + std::to_string(r.step) + ": non-finite loss or gradient, step skipped (" +
             std::to_string(s.bad_in_a_row) + " in a row)");
  if (s.bad_in_a_row >= config_.get<TrainConfig>().max_bad_steps)
    throw TrainingDiverged("training diverged: " + std::to_string(s.bad_in_a_row) +
                           " consecutive non-finite steps at step " + std::to_string(r.step) +
                           "; the last checkpoint (" + s.run.checkpoint_path() +
                           ") is intact. Lower train.lr_init or check the data.");
}

void Trainer::log_step(const StepReport& r) {
  auto& s = *s_;
  const TrainConfig& tc = config_.get<TrainConfig>();
  if (!s.leader || r.step < 0 || !r.finite) return;
  s.loss_acc += r.loss;
  s.mse_fine_acc += r.mse_fine;
  for (size_t t = 0; t < r.terms.size(); ++t) s.terms_acc[t] += r.terms[t];
  s.acc_steps++;
  const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - s.rate_clock).count();
  if (secs > kRateWindowS) {
    s.rays_per_s = static_cast<double>(s.rays_since_log) / secs;
    s.rays_since_log = 0;
    s.rate_clock = std::chrono::steady_clock::now();
  }
  if (!opts_.quiet && s.progress) {
    char fields[160];
    std::snprintf(fields, sizeof fields, "loss %.5f psnr %.2f lr %.2e %.0f rays/s", r.loss, psnr_from_mse(r.mse_fine),
                  r.lr, s.rays_per_s);
    s.progress->update(s.state.step, fields, false, schedule_fraction());
  }
  if (r.step % tc.log_every == 0 || r.step == tc.steps) {
    const auto n = static_cast<double>(s.acc_steps);
    // The loss's terms that are in play (a term that is zero over the whole window is left out).
    nlohmann::json terms = nlohmann::json::object();
    for (size_t t = 0; t < s.terms_acc.size(); ++t)
      if (s.terms_acc[t] != 0) terms[kLossTermNames[t]] = s.terms_acc[t] / n;
    append_run_log(s.run.log_path(), {{"type", "train"},
                                      {"step", r.step},
                                      {"loss", s.loss_acc / n},
                                      {"terms", terms},
                                      {"psnr", psnr_from_mse(s.mse_fine_acc / n)},
                                      {"lr", r.lr},
                                      {"rays_per_s", s.rays_per_s},
                                      {"elapsed_s", s.state.elapsed_seconds}});
    s.loss_acc = s.mse_fine_acc = 0;
    s.terms_acc.fill(0.0);
    s.acc_steps = 0;
  }
}

std::vector<int64_t> held_out_views(int64_t size, int64_t count) {
  std::vector<int64_t> views;
  const int64_t n = std::min(std::max<int64_t>(count, 0), std::max<int64_t>(size, 0));
  for (int64_t i = 0; i < n; ++i) views.push_back(i * size / n);
  return views;
}

// Mean PSNR of the fine colour on train.eval_views images spread over the held-out split.
void Trainer::held_out_check() {
  auto& s = *s_;
  const TrainConfig& tc = config_.get<TrainConfig>();
  if (!s.leader || tc.eval_every <= 0 || s.held_out.empty()) return;
  if (s.state.step % tc.eval_every != 0 && s.state.step != tc.steps) return;
  flush();
  const Split& split = s.ds->split(s.held_out);
  s.model->eval();
  double sum = 0;
  const std::vector<int64_t> views = held_out_views(split.size(), tc.eval_views);
  for (const int64_t i : views) {
    RenderResult img = render_image(s.model, split.c2w[i], split.cameras.at(static_cast<size_t>(i)), s.near, s.far,
                                    config_.get<EvalConfig>().chunk, {}, opts_.device);
    sum += psnr(img.rgb.cpu(), split.images[i]);
  }
  s.model->train();
  const double p = views.empty() ? NAN : sum / static_cast<double>(views.size());
  append_run_log(s.run.log_path(), {{"type", "eval"},
                                    {"step", s.state.step},
                                    {"psnr", p},
                                    {"views", tc.eval_views},
                                    {"view_indices", views},
                                    {"split", s.held_out},
                                    {"elapsed_s", s.state.elapsed_seconds}});
  if (!opts_.quiet) {
    std::ostringstream line;
    line << "train: step " << s.state.step << " held-out " << s.held_out << " PSNR " << p << " dB";
    log_info(line.str());
  }
}

TrainResult Trainer::run() {
  auto& s = *s_;
  const TrainConfig& tc = config_.get<TrainConfig>();
  s.progress.emplace("train", tc.steps, kProgressIntervalS);
  const auto this_run_seconds = [&] {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - s.start).count();
  };
  while (s.state.step < tc.steps) {
    if (!opts_.dist) s.agreed_elapsed = s.local_elapsed();
    if (tc.time_budget_s > 0 && schedule_fraction() >= 1.0) {
      if (s.leader && !opts_.quiet) {
        std::ostringstream line;
        line << "train: time budget of " << tc.time_budget_s << " s spent at step " << s.state.step;
        log_info(line.str());
      }
      break;
    }
    if (g_interrupt.load()) {
      save();
      if (s.leader) log_warn("train: interrupted; checkpoint saved at step " + std::to_string(s.state.step));
      return TrainResult::Interrupted;
    }
    const bool step_limit = opts_.max_steps_this_run >= 0 && s.steps_this_run >= opts_.max_steps_this_run;
    // With several processes the agreed clock decides, so every rank stops at the same step.
    const double limit_clock = opts_.dist ? s.agreed_elapsed - s.elapsed_before : this_run_seconds();
    const bool time_limit = opts_.time_limit_s > 0 && limit_clock >= opts_.time_limit_s;
    if (step_limit || time_limit) {
      save();
      if (time_limit && s.leader && !opts_.quiet)
        log_info("train: time limit reached at step " + std::to_string(s.state.step) +
                 "; checkpoint saved (--resume continues)");
      return TrainResult::StoppedEarly;
    }
    const StepReport r = step();
    s.steps_this_run++;
    s.rays_since_log += tc.rays_per_step;
    check_divergence(r);
    log_step(r);
    held_out_check();
    if (tc.ckpt_every > 0 && s.state.step % tc.ckpt_every == 0 && s.state.step < tc.steps) save();
    if (opts_.between_steps) opts_.between_steps(*this);
  }
  const StepReport last = flush();
  if (s.cuda) {
    check_divergence(last);
    log_step(last);
  }
  save();
  if (s.leader && !opts_.quiet) s.progress->finish("done");
  if (s.leader) report_coverage();
  return TrainResult::Finished;
}

void Trainer::report_coverage() {
  auto& s = *s_;
  const TrainConfig& tc = config_.get<TrainConfig>();
  const double passes = passes_per_pixel(s.state.step, tc.rays_per_step, s.sampler->pixels());
  append_run_log(
      s.run.log_path(),
      {{"type", "coverage"}, {"step", s.state.step}, {"pixels", s.sampler->pixels()}, {"passes_per_pixel", passes}});
  if (opts_.quiet) return;
  std::ostringstream line;
  line.precision(2);
  line << std::fixed << "train: " << s.state.step << " steps of " << tc.rays_per_step << " rays drew each of the "
       << s.sampler->pixels() << " training pixels " << passes << " times on average";
  log_info(line.str());
  const Intrinsics& k = s.ds->intrinsics;
  const std::string advice =
      coverage_advice(passes, config_.get<DataConfig>().downscale, tc.time_budget_s, std::min(k.width, k.height));
  if (!advice.empty()) log_warn(advice);
}

double passes_per_pixel(int64_t steps, int64_t rays_per_step, int64_t pixels) {
  if (pixels <= 0) return 0.0;
  return static_cast<double>(steps) * static_cast<double>(rays_per_step) / static_cast<double>(pixels);
}

std::string coverage_advice(double passes, int downscale, double budget_s, int short_side) {
  if (passes >= kFewPasses || passes <= 0) return std::string();
  const double factor = kFewPasses / passes;
  std::ostringstream out;
  out.precision(1);
  out << std::fixed << "train: under " << kFewPasses << " passes per pixel, so fine detail was still forming: ";
  out.precision(0);
  out << "train about " << factor << "x ";
  if (budget_s > 0)
    out << "longer (--time-budget " << std::ceil(budget_s * factor / 60.0) << "m)";
  else
    out << "more steps";
  const int smaller = static_cast<int>(std::ceil(downscale * std::sqrt(factor)));
  // The short side the smaller images would keep.
  if (static_cast<int64_t>(short_side) * downscale / smaller >= kSmallestAdvisedSide)
    out << " or on smaller images (--downscale " << smaller << ")";
  return out.str();
}

void Trainer::checkpoint_now() { save(); }

TrainResult train(const Config& config, const TrainOptions& opts) {
  Trainer t(config, opts);
  t.setup();
  return t.run();
}

}  // namespace ablenerf
