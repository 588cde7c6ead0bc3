#pragma once
// Run configuration: one schema, enforced. Every key lives in exactly one place (the
// visitor in config.cpp), is read from TOML, can be overridden as `--set section.key=value`,
// and is written back as the run's resolved config. Unknown keys are errors.
#include <cstdint>
#include <optional>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

namespace ablenerf {

// How the model's arithmetic runs (model/compute.h). Never changes what is computed beyond rounding.
enum class AttentionKernel { Fused, Plain };
enum class Precision { Fp32, Bf16 };
enum class CpuSplit { Rays, Ops };
// What the run computes or reads, chosen by name in the config.
enum class ViewEncoding { Release, Paper };  // model.view_encoding (model/view_encoding.h)
enum class Background { White, Black };      // data.background: the colour RGBA images are composited on
enum class RaySampling { Uniform, Error };   // train.ray_sampling (train/error_map.h)
enum class Embedding { Ipe, Grid };  // model.embedding: the paper's IPE or the grid front end (model/grid_embedding.h)
// data.scene (data/scene_frame.h): where samples lie along a ray and how they are encoded.
//  * Bounded: depth-linear samples between near and far (Blender's object on a card);
//  * Unbounded: mip-NeRF 360's scene contraction of the frustum Gaussians, half the samples linear
//    in depth inside the cameras' sphere, half linear in disparity out to (practically) infinity;
//  * ForwardFacing: NeRF's normalised device coordinates (model/ndc.h) for captures whose cameras all
//    look the same way at a scene in front of them (LLFF): samples linear in disparity to infinity;
//  * Auto: Bounded for Blender scenes; for real captures ForwardFacing when every camera looks
//    within kForwardFacingMaxAngleDeg of their mean direction and the capture knows how near its
//    scene comes (sparse points or LLFF bounds), else Unbounded.
enum class SceneKind { Auto, Bounded, Unbounded, ForwardFacing };
// data.masks (data/dataset.h): which pixels of the photos train. Auto: the masks the capture comes
// with (a masks/ folder, nerfstudio's mask_path, instant-ngp's dynamic_mask_*), every pixel when it
// has none; None (the default): every pixel; Alpha: the pixels whose alpha is at least 0.5 (RGBA
// photos).
enum class MaskSource { Auto, None, Alpha };
// eval.ssim (eval/metrics.h):
enum class SsimVariant {
  // mip-NeRF / multinerf: 11x11 Gaussian (sigma 1.5), valid convolution (no padding), mean over
  // the valid map and channels; variances clamped at 0 and the covariance bounded by
  // sqrt(var_x var_y) as in multinerf. Needs images of at least 11x11.
  Standard,
  // The ABLE-NeRF authors' release: same window, zero padding of 5 ("same"-size map), mean over
  // the full map including the zero-padded borders, no clamping (biased low near borders).
  Release,
};

// The names of an enum's values, one table per enum (config files, --set, logs, bench reports).
template <class E>
using EnumNames = std::vector<std::pair<E, const char*>>;
template <class E>
inline const EnumNames<E> kEnumNames;  // specialised for every enum below
template <>
inline const EnumNames<AttentionKernel> kEnumNames<AttentionKernel>{{AttentionKernel::Fused, "fused"},
                                                                    {AttentionKernel::Plain, "plain"}};
template <>
inline const EnumNames<Precision> kEnumNames<Precision>{{Precision::Fp32, "fp32"}, {Precision::Bf16, "bf16"}};
template <>
inline const EnumNames<CpuSplit> kEnumNames<CpuSplit>{{CpuSplit::Rays, "rays"}, {CpuSplit::Ops, "ops"}};
template <>
inline const EnumNames<ViewEncoding> kEnumNames<ViewEncoding>{{ViewEncoding::Release, "release"},
                                                              {ViewEncoding::Paper, "paper"}};
template <>
inline const EnumNames<Background> kEnumNames<Background>{{Background::White, "white"}, {Background::Black, "black"}};
template <>
inline const EnumNames<RaySampling> kEnumNames<RaySampling>{{RaySampling::Uniform, "uniform"},
                                                            {RaySampling::Error, "error"}};
template <>
inline const EnumNames<Embedding> kEnumNames<Embedding>{{Embedding::Ipe, "ipe"}, {Embedding::Grid, "grid"}};
template <>
inline const EnumNames<SceneKind> kEnumNames<SceneKind>{{SceneKind::Auto, "auto"},
                                                        {SceneKind::Bounded, "bounded"},
                                                        {SceneKind::Unbounded, "unbounded"},
                                                        {SceneKind::ForwardFacing, "forward"}};
template <>
inline const EnumNames<MaskSource> kEnumNames<MaskSource>{
    {MaskSource::Auto, "auto"}, {MaskSource::None, "none"}, {MaskSource::Alpha, "alpha"}};
template <>
inline const EnumNames<SsimVariant> kEnumNames<SsimVariant>{{SsimVariant::Standard, "standard"},
                                                            {SsimVariant::Release, "release"}};

template <class E>
const EnumNames<E>& enum_names() {
  static_assert(std::is_enum_v<E>, "enum_names: not an enum");
  return kEnumNames<E>;
}
template <class E>
const char* name_of(E value) {
  for (const auto& [v, n] : enum_names<E>())
    if (v == value) return n;
  return "?";
}
template <class E>
std::optional<E> enum_from_name(const std::string& name) {
  for (const auto& [v, n] : enum_names<E>())
    if (name == n) return v;
  return std::nullopt;
}

struct ModelConfig {
  int width = 192;        // token width d
  int heads = 3;          // attention heads (head dim = width / heads)
  int ff_ratio = 3;       // feed-forward width = width * ff_ratio
  int coarse_layers = 2;  // AB transformer blocks, coarse pass
  int fine_layers = 6;    // AB transformer blocks, fine pass
  int samples = 96;       // intervals per ray (coarse and fine)
  // What turns a frustum Gaussian into the features of its token: "ipe", the paper's integrated
  // positional encoding (stage 2), or "grid", a multiresolution hash grid (model/grid_embedding.h).
  Embedding embedding = Embedding::Ipe;
  int ipe_degrees = 16;  // IPE frequencies 2^0 .. 2^(ipe_degrees-1)
  // The grid front end (model.embedding = "grid"): levels of 2^grid_log2_table rows of
  // grid_features floats, from grid_base_resolution to grid_max_resolution cells per side.
  int grid_levels = 16;
  int grid_features = 2;
  int grid_log2_table = 19;
  int grid_base_resolution = 16;
  int grid_max_resolution = 2048;
  // IPE frequencies 2^0 .. 2^(grid_ipe_degrees-1) put beside the grid's features in the token (0 =
  // the grid alone): the grid carries no position of its own, and without it the transformer
  // memorised the training rays of a real capture (docs/BENCHMARKS.md, "Grid front end").
  int grid_ipe_degrees = 4;
  double grid_lr_scale = 20;  // the table's learning rate over the run's (instant-ngp's 1e-2 at lr 5e-4)
  double grid_bound = 1.5;    // bounded scenes: the grid spans [-grid_bound, grid_bound]^3 of the world
  // The proposal field (model/proposal.h; docs/MODEL.md, "Proposal sampling"): a small density grid
  // read at proposal_samples intervals of every ray places the coarse pass's samples where the
  // surfaces are, in place of the paper's even spacing. 0 = off (the paper). Its hash grid:
  // proposal_levels levels from grid_base_resolution to proposal_max_resolution cells per side, of
  // 2^proposal_log2_table rows (learning rate scaled by grid_lr_scale as the front end's).
  int proposal_samples = 0;
  int proposal_levels = 5;
  int proposal_max_resolution = 128;
  int proposal_log2_table = 16;
  int le_count = 32;        // learnable embeddings; 0 = the paper's "no LE" ablation
  int le_layers = 2;        // LE self-attention blocks
  bool mask = true;         // causal volume mask (docs/MODEL.md, section 4) (false = bidirectional ablation)
  bool randomized = false;  // stratified jitter of coarse samples and resampling (released: off)
  ViewEncoding view_encoding = ViewEncoding::Release;  // "release": d, 4 linear freqs 1..8; "paper": 16 octave bands
  double resample_padding = 0.01;                      // added to every blurred weight before inverse-CDF sampling
};

struct DataConfig {
  int downscale = 1;  // integer box-downscale factor
  Background background = Background::White;
  // Near/far of Blender scenes (their convention: 2/6). A real capture's bounds come from the
  // capture itself (sparse points, LLFF bounds or the camera layout; data/scene_frame.h) unless
  // bounds = "config".
  double near = 2.0;
  double far = 6.0;
  SceneKind scene = SceneKind::Auto;
  bool bounds_from_config = false;  // data.bounds_from_config: use near/far for captures too
  // Off by default: on the gold cape (object masks) training on the masked pixels only cost 0.8 dB
  // on the object at 15 minutes (docs/BENCHMARKS.md, "The capture preset and the peer").
  MaskSource masks = MaskSource::None;
};

struct TrainConfig {
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
  double coarse_weight = 1.0;
  double fine_weight = 1.0;
  // mip-NeRF 360's distortion loss (Barron et al. 2022, section 4) on the fine pass's attention
  // over the samples, as a distribution, in the normalised ray coordinate (train/regularisers.h):
  // pulls each ray's attention onto one compact stretch. 0 = off (the paper).
  double distortion_weight = 0.0;
  // Zip-NeRF's normalised weight decay on the grid front end's table (Barron et al. 2023: the sum over
  // levels of each level's mean squared feature), weighted by this. 0 = off.
  double grid_decay = 0.0;
  // Weight of mip-NeRF 360's proposal loss (section 3, eq. 13-14; train/regularisers.h), which trains
  // the proposal field (model.proposal_samples > 0) to bound the fine pass's attention. nerfacto's 1.
  double proposal_weight = 1.0;
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
  // On CUDA (one process, LibTorch >= 2): capture the training step as one CUDA graph and replay
  // it (false: the same device step, run eagerly). Ignored elsewhere.
  bool graph = true;
};

struct EvalConfig {
  int64_t chunk = 4096;                      // rays per forward when rendering
  SsimVariant ssim = SsimVariant::Standard;  // "standard" (valid 11x11 Gaussian) | "release" (zero-padded)
};

// How the arithmetic runs (model/compute.h); never changes what is computed beyond rounding.
struct ComputeConfig {
  Precision precision = Precision::Fp32;  // "fp32" | "bf16" (CUDA autocast; weights, loss, optimiser in fp32)
  // "fused" (CPU: packed BLAS kernel; CUDA: the project's ray-attention kernel where it applies,
  // else SDPA) | "plain" (explicit softmax)
  AttentionKernel attention = AttentionKernel::Fused;
  // CPU threads: "rays" = each thread runs a slice of the rays through the whole model with
  // single-threaded BLAS; "ops" = one ray batch, threads only inside the libraries' ops.
  CpuSplit cpu_split = CpuSplit::Rays;
};

struct Config {
  ModelConfig model;
  DataConfig data;
  TrainConfig train;
  EvalConfig eval;
  ComputeConfig compute;
  std::string source = "<defaults>";  // where it came from, for error messages

  // Loads a TOML file over the defaults. Throws InputError(file, key, ...) on any problem.
  static Config load(const std::string& toml_path);
  // Parses TOML text (`origin` names it in errors).
  static Config parse(const std::string& toml_text, const std::string& origin);
  // Applies "section.key=value"; throws InputError("--set", key, ...).
  void set(const std::string& assignment);
  // Checks ranges and consistency; throws InputError(source, key, ...).
  void validate() const;
  // The full resolved config as TOML text (every key).
  std::string to_toml() const;
  // All keys with their current values as strings, in schema order.
  std::vector<std::pair<std::string, std::string>> items() const;
};

}  // namespace ablenerf
