#pragma once
// The [train] section of the run configuration (util/config_section.h), registered below: the training recipe
// (docs/MODEL.md, section 8, and the extensions it lists), owned by the train module.
#include <cmath>
#include <cstdint>

#include "model/coarse_work.h"
#include "model/photo_colour_map.h"
#include "util/config_section.h"

namespace ablenerf {

enum class RaySampling { Uniform, Error };  // train.ray_sampling (train/error_map.h)

template <>
inline const EnumNames<RaySampling> kEnumNames<RaySampling>{{RaySampling::Uniform, "uniform"},
                                                            {RaySampling::Error, "error"}};

struct TrainConfig {
  static constexpr const char* kName = "train";
  static constexpr int kOrder = 2;

  int64_t steps = 234375;        // optimiser steps
  int64_t rays_per_step = 8192;  // global batch
  int64_t micro_batch = 1024;    // rays per forward/backward (gradient accumulation)
  double lr_init = 5e-4;
  double lr_final = 1e-4;
  int64_t lr_warmup_steps = 1250;
  double lr_warmup_mult = 0.01;
  int64_t lr_decay_steps = 250000;  // log-linear decay length; 0 = the step budget
  // Adam's constants (train/adam.h). The release's: (0.9, 0.999), 1e-8.
  double adam_beta1 = 0.9;
  double adam_beta2 = 0.999;
  double adam_eps = 1e-8;
  double coarse_weight = 1.0;  // 0: the coarse colour is not computed (train/grad_accumulation.h)
  // The coarse colour with the coarse pass's learnable embeddings (the paper), or false: from its
  // ray token alone, without the coarse LE transformer (CoarseWork::le).
  bool coarse_le = true;
  // With coarse_le false: the coarse colour's view-dependent part from the coarse LE colour head on
  // the coarse ray token and the view direction (CoarseWork::view_head), or none.
  bool coarse_view_head = false;
  // The coarse pass's work these three settings ask of a training forward (the step's forward
  // options and bench's FLOP count both read it).
  CoarseWork coarse_work() const { return {coarse_weight > 0, coarse_le, coarse_view_head}; }
  double fine_weight = 1.0;
  // mip-NeRF 360's distortion loss (Barron et al. 2022, section 4) on the fine pass's attention
  // over the samples, as a distribution, in the normalised ray coordinate (train/regularisers.h):
  // pulls each ray's attention onto one compact stretch. 0 = off (the paper).
  double distortion_weight = 0.0;
  // Where in the schedule (its share, as for coarse_pixel_until) the distortion term begins: off
  // before it, then its weight rises linearly to the full distortion_weight over the next
  // distortion_ramp of the schedule (train/regularisers.h, distortion_ramp). 0 = on from the first step. From the
  // start, 0.01 gathered the attention of a phone video's rays before they had found its surfaces and left them there
  // (-6 dB); begun at 0.5 the same weight reads the depth of lego and the demo scene and costs no image
  // (docs/benchmarks/history.md, "The demo scene at its own size, and the distortion term begun halfway").
  double distortion_start = 0.0;
  // The part of the schedule over which the term rises from 0 to its weight after
  // distortion_start (0 = at once).
  double distortion_ramp = 0.1;
  // Whether the distortion term trains captures whose cameras all face one way too (the scene
  // frame's faces_one_way: LLFF's layout, contracted or in NDC). false: the trainer sets
  // distortion_weight to 0 for such a capture and says so; the run's config.toml records the 0.
  // Begun halfway, 0.01 cost LLFF's fern 0.5 dB and horns 0.8 dB, while captures with cameras all
  // round their subject scored as without it (docs/benchmarks/history.md, "The distortion term on
  // forward-facing captures").
  bool distortion_forward_facing = true;
  // "Floaters No More" (Philip and Deschaintre 2023): each sample token's gradient is scaled by
  // min(1, (t / near_gradient_distance)^2), t its depth along the ray in scene units (the farthest
  // camera at 1 from the scene's centre, model/scene_frame.h), so that samples close to a camera,
  // which few other views see, learn slower than the surfaces the views share: fewer floaters and
  // less fog in front of the cameras. The forward is unchanged. 0 = off (every preset): at 1 it cost
  // an office photographed from inside 2.3 dB, where everything seen is near the cameras, and gained
  // 0.6-1.0 dB on subjects far from them (docs/benchmarks/history.md, "Gradients scaled near the cameras").
  double near_gradient_distance = 0.0;
  // The same distance relative to the capture: this multiple of the scene's near plane (the nearest
  // content the sparse points or the capture's bounds put before a camera, model/scene_frame.h), so
  // that an office's cameras a few tenths from its walls and a building's far behind its trees get
  // each its own; the larger of the two distances is used (near_gradient_distance_for). 0 = off
  // (every preset): at 2 the zoo's means moved by under 0.1 dB (docs/benchmarks/history.md, "The
  // gradient scaling relative to the near plane").
  double near_gradient_near_multiple = 0.0;
  // Zip-NeRF's normalised weight decay on the grid front end's table (Barron et al. 2023: the sum over
  // levels of each level's mean squared feature), weighted by this. 0 = off.
  double grid_decay = 0.0;
  // Weight of mip-NeRF 360's proposal loss (section 3, eq. 13-14; train/regularisers.h), which trains
  // the proposal field (model.proposal_samples > 0) to bound the fine pass's attention. nerfacto's 1.
  double proposal_weight = 1.0;
  // The same loss the other way round: the fine attention drawn towards what the proposal field
  // (one density shared by every ray) can bound, the field held constant. 0 = off (the attention
  // only ever learns from the colour).
  double proposal_attention_weight = 0.0;
  // Per-photo colour (model/photo_colour.h; docs/MODEL.md, "Per-photo colour"): a map of the
  // rendered colour per training photo for its exposure and white balance, held near the identity
  // by photo_colour_decay x the photos' mean squared parameter. Off = the paper. photo_colour_map:
  // "affine" (3x4 on the sRGB colour) or "gain" (three gains on the linear light, as a camera's
  // exposure and white balance act).
  bool photo_colour = false;
  PhotoColourMap photo_colour_map = PhotoColourMap::Affine;
  double photo_colour_decay = 1e-4;
  // Camera refinement (model/camera_refine.h; docs/MODEL.md, "Camera refinement"): a rigid
  // correction per training photo learned with the scene, held near zero by camera_refine_decay x
  // the cameras' mean squared correction. Off = the poses as given (the paper).
  bool camera_refine = false;
  double camera_refine_decay = 1e-4;
  // With camera_refine: also one focal-length scale for the whole capture (model/camera_refine.h),
  // used by eval, render and `export --cameras` too. Off = the focal length as given.
  bool camera_refine_focal = false;
  // Per-photo appearance codes (model/appearance_code.h; docs/MODEL.md, "Per-photo appearance
  // code"): a code of the model's width per training photo on its rays' view token, held near the
  // photos' mean by appearance_code_decay x the photos' mean squared code. Needs the learnable
  // embeddings (model.le_count > 0). Off = the paper.
  bool appearance_code = false;
  double appearance_code_decay = 1e-4;
  // BARF's coarse-to-fine schedule with camera refinement (model/camera_refine.h,
  // coarse_to_fine_alpha): the IPE's bands open one by one between these shares of the run
  // (e.g. 0.1 and 0.5, BARF's); end = 0: off, every band open throughout.
  double camera_refine_c2f_start = 0;
  double camera_refine_c2f_end = 0;
  int64_t seed = 4;
  int64_t log_every = 100;    // steps between log.jsonl lines
  int64_t eval_every = 5000;  // steps between held-out PSNR checks (0 = never)
  int64_t eval_views = 4;     // held-out views used for that check, spread evenly over the split
  int64_t ckpt_every = 5000;  // steps between checkpoints (0 = only at the end)
  int64_t max_bad_steps = 5;  // consecutive non-finite losses before the run stops
  // Wall-clock budget in seconds (0 = none). With one, the learning-rate schedule advances by
  // whichever is further along, steps or time, and training ends when either runs out, so a run
  // finishes in its budget on a slow machine with its schedule complete. With several processes
  // the ranks agree on the elapsed time (the mean over the group, every step).
  double time_budget_s = 0;
  // Which pixels a step's rays come from (train/error_map.h): "uniform" = every training pixel
  // equally likely; "error" = a tile of error_tile x error_tile pixels in proportion to the recent
  // squared error of its rays, mixed with uniform sampling at error_uniform_share. error_tile is at
  // most 256 pixels (a pixel's place inside its tile is kept in 16 bits).
  RaySampling ray_sampling = RaySampling::Uniform;
  int64_t error_tile = 4;
  double error_uniform_share = 0.25;
  // Coarse pixels first (train/ray_batch.h; docs/MODEL.md, "Coarse pixels first"): a share of a
  // step's rays are pixels of the training images reduced coarse_pixel_factor times (each the mean
  // of its block, cast as one wider cone through the block's centre), coarse_pixel_share of the
  // rays at the start, falling linearly to none at coarse_pixel_until of the schedule. 0 = off.
  double coarse_pixel_share = 0;
  int64_t coarse_pixel_factor = 2;
  double coarse_pixel_until = 0.5;
  // On CUDA (one process, LibTorch >= 2): capture the training step as one CUDA graph and replay
  // it (false: the same device step, run eagerly). Ignored elsewhere.
  bool graph = true;

  template <class F>
  void visit(F&& f) {
    f("steps", &steps);
    f("rays_per_step", &rays_per_step);
    f("micro_batch", &micro_batch);
    f("lr_init", &lr_init);
    f("lr_final", &lr_final);
    f("lr_warmup_steps", &lr_warmup_steps);
    f("lr_warmup_mult", &lr_warmup_mult);
    f("lr_decay_steps", &lr_decay_steps);
    f("adam_beta1", &adam_beta1);
    f("adam_beta2", &adam_beta2);
    f("adam_eps", &adam_eps);
    f("coarse_weight", &coarse_weight);
    f("coarse_le", &coarse_le);
    f("coarse_view_head", &coarse_view_head);
    f("fine_weight", &fine_weight);
    f("distortion_weight", &distortion_weight);
    f("distortion_start", &distortion_start);
    f("distortion_ramp", &distortion_ramp);
    f("distortion_forward_facing", &distortion_forward_facing);
    f("near_gradient_distance", &near_gradient_distance);
    f("near_gradient_near_multiple", &near_gradient_near_multiple);
    f("grid_decay", &grid_decay);
    f("proposal_weight", &proposal_weight);
    f("proposal_attention_weight", &proposal_attention_weight);
    f("photo_colour", &photo_colour);
    f("photo_colour_map", &photo_colour_map);
    f("photo_colour_decay", &photo_colour_decay);
    f("camera_refine", &camera_refine);
    f("camera_refine_decay", &camera_refine_decay);
    f("camera_refine_focal", &camera_refine_focal);
    f("appearance_code", &appearance_code);
    f("appearance_code_decay", &appearance_code_decay);
    f("camera_refine_c2f_start", &camera_refine_c2f_start);
    f("camera_refine_c2f_end", &camera_refine_c2f_end);
    f("seed", &seed);
    f("log_every", &log_every);
    f("eval_every", &eval_every);
    f("eval_views", &eval_views);
    f("ckpt_every", &ckpt_every);
    f("max_bad_steps", &max_bad_steps);
    f("time_budget_s", &time_budget_s);
    f("ray_sampling", &ray_sampling);
    f("error_tile", &error_tile);
    f("error_uniform_share", &error_uniform_share);
    f("coarse_pixel_share", &coarse_pixel_share);
    f("coarse_pixel_factor", &coarse_pixel_factor);
    f("coarse_pixel_until", &coarse_pixel_until);
    f("graph", &graph);
  }

  void validate(const SectionCheck& need) const {
    need(steps >= 0, "steps", "must be >= 0");
    need(rays_per_step >= 1, "rays_per_step", "must be >= 1");
    need(micro_batch >= 1, "micro_batch", "must be >= 1");
    need(lr_init > 0 && lr_final > 0, "lr_init", "learning rates must be positive");
    need(lr_warmup_steps >= 0, "lr_warmup_steps", "must be >= 0");
    need(lr_warmup_mult > 0 && lr_warmup_mult <= 1, "lr_warmup_mult", "must be in (0, 1]");
    need(lr_decay_steps >= 0, "lr_decay_steps", "must be >= 0");
    need(adam_beta1 >= 0 && adam_beta1 < 1, "adam_beta1", "must be in [0, 1)");
    need(adam_beta2 >= 0 && adam_beta2 < 1, "adam_beta2", "must be in [0, 1)");
    need(adam_eps > 0 && std::isfinite(adam_eps), "adam_eps", "must be > 0");
    need(coarse_weight >= 0 && fine_weight >= 0, "fine_weight", "loss weights must be >= 0");
    need(distortion_weight >= 0 && std::isfinite(distortion_weight), "distortion_weight", "must be >= 0");
    need(distortion_start >= 0 && distortion_start < 1, "distortion_start", "must be in [0, 1)");
    need(distortion_ramp >= 0 && distortion_ramp <= 1, "distortion_ramp", "must be in [0, 1]");
    need(near_gradient_distance >= 0 && std::isfinite(near_gradient_distance), "near_gradient_distance",
         "must be >= 0");
    need(near_gradient_near_multiple >= 0 && std::isfinite(near_gradient_near_multiple), "near_gradient_near_multiple",
         "must be >= 0");
    need(grid_decay >= 0 && std::isfinite(grid_decay), "grid_decay", "must be >= 0");
    need(proposal_weight >= 0 && std::isfinite(proposal_weight), "proposal_weight", "must be >= 0");
    need(proposal_attention_weight >= 0 && std::isfinite(proposal_attention_weight), "proposal_attention_weight",
         "must be >= 0");
    need(photo_colour_decay >= 0 && std::isfinite(photo_colour_decay), "photo_colour_decay", "must be >= 0");
    need(camera_refine_decay >= 0 && std::isfinite(camera_refine_decay), "camera_refine_decay", "must be >= 0");
    need(!camera_refine_focal || camera_refine, "camera_refine_focal", "needs train.camera_refine = true");
    need(appearance_code_decay >= 0 && std::isfinite(appearance_code_decay), "appearance_code_decay", "must be >= 0");
    need(camera_refine_c2f_start >= 0 && camera_refine_c2f_start < 1, "camera_refine_c2f_start", "must be in [0, 1)");
    need(camera_refine_c2f_end == 0 || (camera_refine_c2f_end > camera_refine_c2f_start && camera_refine_c2f_end <= 1),
         "camera_refine_c2f_end", "must be 0 (off) or in (camera_refine_c2f_start, 1]");
    need(log_every >= 1, "log_every", "must be >= 1");
    need(eval_every >= 0, "eval_every", "must be >= 0");
    need(eval_views >= 0, "eval_views", "must be >= 0");
    need(ckpt_every >= 0, "ckpt_every", "must be >= 0");
    need(max_bad_steps >= 1, "max_bad_steps", "must be >= 1");
    need(time_budget_s >= 0 && std::isfinite(time_budget_s), "time_budget_s", "must be >= 0 seconds");
    // The map keeps a masked pixel's place in its tile in 16 bits (train/error_map.h).
    need(error_tile >= 1 && error_tile <= 256, "error_tile", "must be in 1..256 pixels");
    need(error_uniform_share >= 0 && error_uniform_share <= 1, "error_uniform_share", "must be in [0, 1]");
    need(coarse_pixel_share >= 0 && coarse_pixel_share <= 1, "coarse_pixel_share", "must be in [0, 1]");
    need(coarse_pixel_factor >= 2 && coarse_pixel_factor <= 64, "coarse_pixel_factor", "must be in 2..64");
    need(coarse_pixel_until > 0 && coarse_pixel_until <= 1, "coarse_pixel_until", "must be in (0, 1]");
  }
};
ABLENERF_CONFIG_SECTION(TrainConfig);

}  // namespace ablenerf
