// Trainer's set-up (train/trainer.h): the run folder (new or resumed), the dataset and its
// held-out split, the checkpoint, and the model, optimiser and ray sampler built for the training
// split. The steps and run()'s hooks are in trainer.cpp.
#include <algorithm>
#include <filesystem>
#include <sstream>
#include <stdexcept>

#include "data/load_options.h"
#include "model/compute.h"
#include "train/distributed.h"
#include "train/image_size.h"
#include "train/trainer_state.h"
#include "util/errors.h"
#include "util/fs.h"
#include "util/log.h"
#include "train/train_config.h"
#include "data/data_config.h"
#include "model/compute_config.h"
#include "model/model_config.h"

namespace fs = std::filesystem;

namespace ablenerf {

using namespace trainer_detail;

void Trainer::setup() {
  auto& s = *s_;
  // Run folder: new, or the one being resumed (whose config must match).
  const bool have_ckpt = fs::exists(fs::path(opts_.out_dir) / "checkpoint.pt");
  if (opts_.resume && have_ckpt) {
    s.run = RunFolder::open(opts_.out_dir);
    if (!opts_.data_dir.empty()) s.run.data_dir = opts_.data_dir;
  } else {
    if (!opts_.resume && have_ckpt)
      throw InputError(opts_.out_dir, "checkpoint.pt",
                       "the run folder already holds a run (use --resume to continue it, or another --out)");
    if (opts_.data_dir.empty()) throw InputError("train", "--data", "required");
    if (s.leader) {
      s.run = RunFolder::create(opts_.out_dir, config_, opts_.data_dir);
    } else {
      s.run.dir = opts_.out_dir, s.run.config = config_, s.run.data_dir = opts_.data_dir;
    }
  }
  if (s.run.data_dir.empty()) throw InputError(s.run.path("run.json"), "data", "missing: give --data");
  if (s.leader) s.run.remove_stale_temporaries();

  // The image size, when the config leaves it to the capture (train/image_size.h); recorded in the
  // run's config below.
  // A resumed run keeps the size it chose (its config.toml holds it).
  if (config_.get<DataConfig>().downscale == 0 && opts_.resume && have_ckpt)
    config_.get<DataConfig>().downscale = s.run.config.get<DataConfig>().downscale;
  if (config_.get<DataConfig>().downscale == 0) {
    if (opts_.dist && config_.get<TrainConfig>().time_budget_s > 0 && config_.get<DataConfig>().auto_rays_per_s <= 0)
      throw InputError(config_.source, "data.downscale",
                       "0 with data.auto_rays_per_s = 0 (a size from the speed measured in each process) needs one "
                       "process when the run has a time budget: give --downscale N or data.auto_rays_per_s");
    const ImageSizeChoice choice = resolve_image_size(config_, s.run.data_dir, opts_.device);
    if (s.leader && !opts_.quiet) log_info("train: " + choice.describe());
  }
  // Data: the training split, and a held-out split for the periodic PSNR (val, else test).
  std::vector<std::string> want{"train"};
  // The capture's metadata, read once (its splits decide the held-out one, then it is loaded).
  Capture capture = read_capture(s.run.data_dir, {}, config_.get<DataConfig>().downscale);
  const auto present = capture.split_names();
  for (const char* name : {"val", "test"})
    if (s.held_out.empty() && std::find(present.begin(), present.end(), name) != present.end()) s.held_out = name;
  if (config_.get<TrainConfig>().eval_every > 0 && s.leader && !s.held_out.empty()) want.push_back(s.held_out);
  LoadOptions lo = load_options_for(config_, want);
  lo.progress = s.leader && !opts_.quiet;
  s.ds = Dataset::load(std::move(capture), s.run.data_dir, lo);
  if (!s.ds->has("train")) throw InputError(s.run.data_dir, "transforms_train.json", "the dataset has no train split");
  if (!s.ds->has(s.held_out)) s.held_out.clear();
  // data.scene resolved from the capture, recorded in the run's config with the scene frame (so
  // that eval and render place samples as training did).
  if (config_.get<DataConfig>().scene == SceneKind::Auto) config_.get<DataConfig>().scene = s.ds->scene.kind;
  // The distortion term kept off a capture whose cameras face one way, when the config says so
  // (train.distortion_forward_facing), recorded in the run's config like the scene kind.
  TrainConfig& tc = config_.get<TrainConfig>();
  const bool distortion_off = tc.distortion_weight > 0 && !tc.distortion_forward_facing && s.ds->scene.faces_one_way;
  if (distortion_off) tc.distortion_weight = 0;
  s.run.config = config_;
  if (s.leader) {
    write_file_atomic(s.run.path("config.toml"), config_.to_toml());
    s.run.write_scene(s.ds->scene);
    if (!opts_.quiet) {
      log_info("train: " + s.ds->format + " capture, " + s.ds->scene.describe());
      for (const auto& note : s.ds->notes) log_info("train: " + note);
      if (distortion_off)
        log_info(
            "train: the cameras face one way: the distortion term is off (train.distortion_forward_facing = false)");
    }
  }

  build(s.ds->split("train"), s.ds->intrinsics);
  if (opts_.resume && have_ckpt) {
    s.state = load_checkpoint(s.run.checkpoint_path(), config_, s.model, s.adam->optim());
    s.adam->from_checkpoint();
    s.sampler->set_rng_state(s.state.rng_state);
    try {
      s.sampler->set_map_state(s.state.error_map);
    } catch (const std::invalid_argument&) {
      throw InputError(s.run.checkpoint_path(), "error_map", "made for another training set (image count or size)");
    }
    s.elapsed_before = s.state.elapsed_seconds;
    s.agreed_elapsed = s.elapsed_before;
    if (s.leader) log_info("train: resumed " + s.run.checkpoint_path() + " at step " + std::to_string(s.state.step));
  }
  if (opts_.dist) {
    opts_.dist->broadcast_parameters(s.model);  // every rank starts from rank 0's weights
    if (s.leader && !opts_.quiet)
      log_info("train: data-parallel over a c10d group of " + std::to_string(s.world) + " process(es)");
  }
}

void Trainer::setup(const Split& train, const Intrinsics& k) { build(train, k); }

void Trainer::build(const Split& train, const Intrinsics& k) {
  auto& s = *s_;
  const TrainConfig& tc = config_.get<TrainConfig>();
  torch::manual_seed(static_cast<uint64_t>(tc.seed));
  if (s.ds) {
    s.near = s.ds->near, s.far = s.ds->far, s.scene = s.ds->scene.kind;
  } else {
    s.scene = config_.get<DataConfig>().scene == SceneKind::Unbounded ? SceneKind::Unbounded : SceneKind::Bounded;
    s.near = config_.get<DataConfig>().near,
    s.far = s.scene == SceneKind::Unbounded ? kUnboundedFar : config_.get<DataConfig>().far;
  }
  const NdcProjection ndc = s.ds ? NdcProjection{s.ds->scene.ndc_a, s.ds->scene.ndc_b} : NdcProjection{};
  s.model = AbleNerf(config_.get<ModelConfig>(), s.scene, ndc);
  s.model->to(opts_.device);
  s.model->set_compute(Compute::from_config(config_.get<ComputeConfig>(), opts_.device, config_.source));
  if (config_.get<ComputeConfig>().precision == Precision::Auto && s.leader && !opts_.quiet)
    log_info(std::string("train: compute.precision \"auto\": ") +
             (s.model->compute().precision == Precision::Bf16
                  ? (opts_.device.is_cpu() ? "bf16 products on this CPU's AMX tiles" : "bf16 autocast")
                  : "fp32 (bf16 needs a CPU with AMX tiles or a GPU)"));
  s.model->train();
  // Per-photo colour, camera refinement and appearance codes: one map, one correction and one code
  // per training photo, made before Adam sees the parameters.
  if (tc.photo_colour) s.model->enable_photo_colour(train.size(), tc.photo_colour_map);
  if (tc.camera_refine) {
    s.model->enable_camera_refine(train.size(), tc.camera_refine_focal);
    s.model->camera_refine()->set_cameras(train.c2w);  // the rig's gauge and the cameras' axes
  }
  if (tc.appearance_code) {
    try {
      s.model->enable_appearance_code(train.size());
    } catch (const std::invalid_argument& e) {  // the model's refusal (no LEs), named by the key
      throw InputError(config_.source, "train.appearance_code", e.what());
    }
  }
  const bool device_form = opts_.dist == nullptr && Adam::device_form_available(opts_.device);
  s.adam = std::make_unique<Adam>(s.model->parameters(), tc.lr_init, device_form,
                                  AdamSettings{tc.adam_beta1, tc.adam_beta2, tc.adam_eps});
  // The grid tables' entries no lookup reaches take no update (kernels/table_gradient.h).
  for (GridEmbeddingImpl* g : s.model->grids()) s.adam->set_entries(g->table_parameter(), g->table_entries_read());
  std::optional<ErrorMapOptions> map;
  if (tc.ray_sampling == RaySampling::Error) map = ErrorMapOptions{tc.error_tile, tc.error_uniform_share};
  s.sampler = std::make_unique<RaySampler>(train, k, opts_.device, static_cast<uint64_t>(tc.seed), map,
                                           tc.coarse_pixel_share > 0 ? tc.coarse_pixel_factor : 0);
  s.schedule.emplace(tc);
  s.local_rays = tc.rays_per_step * (s.rank + 1) / s.world - tc.rays_per_step * s.rank / s.world;
  s.micro = std::min<int64_t>(tc.micro_batch, std::max<int64_t>(s.local_rays, 1));
  if (tc.distortion_weight > 0 && tc.distortion_start > 0)
    s.distortion_scale = torch::zeros({}, torch::TensorOptions().device(opts_.device).dtype(torch::kFloat));
  if (s.leader && log_enabled(LogLevel::Debug)) {
    std::ostringstream line;
    line << "train: " << s.model->parameter_count() << " parameters on " << opts_.device << ", " << s.local_rays
         << " rays per step in micro-batches of " << s.micro << ", " << train.size() << " training images, "
         << (device_form ? "device-side Adam" : "host Adam");
    log_debug(line.str());
  }
  if (device_form) {
    s.cuda = std::make_unique<CudaStep>(opts_.device, tc.graph, kGraphWarmupSteps);
    const auto dev = torch::TensorOptions().device(opts_.device);
    s.indices_dev = torch::zeros({s.local_rays}, dev.dtype(torch::kLong));
    s.figures_dev = torch::zeros({kFigureRays + (map ? s.local_rays : 0)}, dev.dtype(torch::kFloat));
  }
  s.start = std::chrono::steady_clock::now();
}

}  // namespace ablenerf
