#pragma once
// The whole ABLE-NeRF forward pass (docs/MODEL.md, sections 1-7), assembled from one module per stage:
// frustum.h -> ipe.h (or grid_embedding.h, model.embedding = "grid") -> volume_embedding.h ->
// ab_transformer.h -> resampler.h -> le_transformer.h (+ view_encoding.h, colour_heads.h) -> tonemap.h.
// Parameter names (for save_weights / import) are documented in docs/weights.md.
#include <torch/torch.h>

#include <string>

#include "data/rays.h"
#include "model/coarse_work.h"
#include "model/compute.h"
#include "model/ab_transformer.h"
#include "model/appearance_code.h"
#include "model/colour_heads.h"
#include "model/grid_embedding.h"
#include "model/le_transformer.h"
#include "model/ndc.h"
#include "model/camera_refine.h"
#include "model/photo_colour.h"
#include "model/proposal.h"
#include "model/volume_embedding.h"
#include "data/data_config.h"
#include "model/model_config.h"

namespace ablenerf {

// Render-time options for the paper's analyses.
struct ForwardOptions {
  bool branches = false;  // also return the two branch colours before tone mapping
  double le_noise = 0.0;  // std of Gaussian noise added to the LE (0 = none)
  bool le_zero = false;   // zero the LE
  CoarseWork coarse;      // what the coarse pass computes beside its attention (model/coarse_work.h)
  // Keep the attention weights (coarse_weights, fine_weights) attached to the graph, for a loss on
  // them (train.distortion_weight); otherwise they are computed without gradient.
  bool weights_grad = false;
  // Scale each sample token's gradient by min(1, (t / near_gradient_distance)^2), t its depth
  // (train.near_gradient_distance); 0 = off. The outputs are unchanged.
  double near_gradient_distance = 0.0;
  // Source of the LE noise and of the stratified jitter (optional). The LE noise is drawn once
  // per forward call; without a generator it comes from a fixed seed, so every chunk of an
  // image sees the same perturbed LE.
  torch::Generator* generator = nullptr;
  // Stratified jitter (model.randomized, training only): uniform [0,1) numbers (B,S+1) for the
  // coarse fence-posts and for the fine inverse-CDF draw. Left undefined, forward() draws both for
  // the whole batch before splitting it (AbleNerfImpl::with_jitter), so the draws never depend on
  // the split.
  torch::Tensor coarse_jitter, fine_jitter;
  // A per-photo appearance code (model/appearance_code.h) added to the view token: (B, width), one
  // per ray, or (1, width) for every ray. Undefined: none, the photos' mean look.
  torch::Tensor appearance;

  // These options for rays [lo, hi) of the batch (the jitter rows and per-ray codes sliced; the rest
  // shared).
  ForwardOptions slice(int64_t lo, int64_t hi) const;
};

// The sample tokens (B, S, width) as they are, their gradient multiplied by min(1, (t / distance)^2)
// with t the middle of each sample's interval (fence_posts (B, S + 1), depths): "Floaters No More"
// (Philip and Deschaintre 2023), ForwardOptions::near_gradient_distance. `tokens` must require grad.
torch::Tensor near_gradient_scaled(torch::Tensor tokens, const torch::Tensor& fence_posts, double distance);

struct ModelOutput {
  torch::Tensor rgb_coarse, rgb_fine;  // (B,3) sRGB in [0,1]; rgb_coarse undefined without coarse.colour
  torch::Tensor coarse_weights;        // (B,S) last coarse layer's ray-token attention over volumes
  torch::Tensor fine_weights;          // (B,S) last fine layer's ray-token attention over volumes
  torch::Tensor fine_t;                // (B,S+1) fine fence-posts (interval i = [t_i, t_i+1])
  torch::Tensor fine_s;                // (B,S+1) the same in the normalised ray coordinate in [0, 1]
  // With the proposal field (model.proposal_samples = N > 0): its fence-posts in the normalised ray
  // coordinate (B,N+1) and its weights (B,N), the latter with their graph for the proposal loss.
  torch::Tensor proposal_s, proposal_weights;
  // With ForwardOptions::branches: linear colours before tone mapping (LE colours are zeros
  // when the model has no LE).
  torch::Tensor ray_colour_coarse, le_colour_coarse, ray_colour_fine, le_colour_fine;

  // Every field, for code that treats them alike (joining the outputs of ray slices). A field
  // added above without being listed here fails the static_assert in able_nerf.cpp.
  static constexpr torch::Tensor ModelOutput::*kFields[] = {
      &ModelOutput::rgb_coarse,       &ModelOutput::rgb_fine,         &ModelOutput::coarse_weights,
      &ModelOutput::fine_weights,     &ModelOutput::fine_t,           &ModelOutput::fine_s,
      &ModelOutput::proposal_s,       &ModelOutput::proposal_weights, &ModelOutput::ray_colour_coarse,
      &ModelOutput::le_colour_coarse, &ModelOutput::ray_colour_fine,  &ModelOutput::le_colour_fine};
};

class AbleNerfImpl : public torch::nn::Module {
 public:
  // `scene` (resolved: Bounded, Unbounded or ForwardFacing; data.scene) sets where the samples lie
  // and whether the frustum Gaussians are contracted (model/contraction.h) or cast around NDC rays
  // (model/ndc.h, with `ndc`'s projection); Auto means Bounded.
  explicit AbleNerfImpl(const ModelConfig& cfg, SceneKind scene = SceneKind::Bounded, NdcProjection ndc = {});
  // Rays must be on the model's device. Stratified jitter (model.randomized) applies only in
  // training mode, drawn for the whole batch (with_jitter) before any split. On the CPU without
  // gradient recording (rendering, evaluation) the rays are split across CPU threads
  // (kernels/cpu_parallel.h); outputs equal the serial ones to float tolerance.
  ModelOutput forward(const Rays& rays, double near, double far, const ForwardOptions& opts = {});
  int64_t parameter_count() const;
  const ModelConfig& config() const { return cfg_; }
  bool unbounded() const { return unbounded_; }
  bool has_le() const { return cfg_.le_count > 0; }
  // The grid front end, or nullptr with the paper's IPE.
  const GridEmbeddingImpl* grid() const { return grid_ ? grid_.get() : nullptr; }
  GridEmbeddingImpl* grid() { return grid_ ? grid_.get() : nullptr; }
  // The proposal field, or nullptr without one (model.proposal_samples = 0, the paper).
  const ProposalImpl* proposal() const { return proposal_ ? proposal_.get() : nullptr; }
  // Every hash grid the model has: the front end's, then the proposal field's.
  std::vector<GridEmbeddingImpl*> grids();
  // Per-photo colour (model/photo_colour.h): registered by the trainer (train.photo_colour) before
  // its optimiser is made, or by load_weights when the weights carry it; never read by forward().
  void enable_photo_colour(int64_t photos, PhotoColourMap map = PhotoColourMap::Affine);
  PhotoColourImpl* photo_colour() { return photo_colour_ ? photo_colour_.get() : nullptr; }
  // Camera refinement (model/camera_refine.h): likewise registered by the trainer
  // (train.camera_refine) or by load_weights; never read by forward() (the trainer corrects the rays).
  void enable_camera_refine(int64_t cameras, bool focal = false);  // focal: train.camera_refine_focal
  CameraRefineImpl* camera_refine() { return camera_refine_ ? camera_refine_.get() : nullptr; }
  // Per-photo appearance codes (model/appearance_code.h): likewise registered by the trainer
  // (train.appearance_code) or by load_weights; forward() reads only ForwardOptions::appearance.
  // Throws std::invalid_argument for a model without learnable embeddings (no view token to add to).
  void enable_appearance_code(int64_t photos);
  AppearanceCodeImpl* appearance_code() { return appearance_code_ ? appearance_code_.get() : nullptr; }
  // True for a parameter of those three per-photo modules: it belongs to one capture's training
  // photos, not to the scene (a model made for viewing has none).
  static bool per_photo_parameter(const std::string& name);
  // How the arithmetic runs (model/compute.h): the attention kernel of every attention layer,
  // the precision of the matrix products (outputs are always fp32) and the CPU ray split.
  void set_compute(const Compute& c);
  // BARF's coarse-to-fine window over the IPE's bands (model/camera_refine.h, train.camera_refine_c2f_*):
  // the trainer sets it before each step; the features of the IPE (the grid front end's IPE bands
  // beside the grid) are scaled by frequency_window_weights(alpha). Kept in one device tensor that
  // is updated in place, so a captured CUDA graph reads the current window. Never set = no window.
  void set_frequency_window(double alpha);
  // The IPE's frequency bands in the sample tokens: model.ipe_degrees, or with the grid front end
  // the coarse bands beside the grid (model.grid_ipe_degrees).
  int64_t ipe_bands() const { return grid_ ? cfg_.grid_ipe_degrees : cfg_.ipe_degrees; }
  const Compute& compute() const { return compute_; }
  // CPU threads a batch of `rays` runs on with this model's ray split: 1 off the CPU, with
  // cpu_split = ops, or when the work draws random numbers (the draws would depend on the split).
  int64_t cpu_ray_workers(int64_t rays, bool draws_randomness) const;
  // `opts` with the stratified jitter of a batch of `rays` drawn (from opts.generator, else
  // LibTorch's stream on the model's device; coarse first, then fine) when the model jitters
  // (model.randomized, training mode) and opts carries none; unchanged otherwise.
  ForwardOptions with_jitter(int64_t rays, ForwardOptions opts) const;

 private:
  struct Pass {
    torch::Tensor ray_token, weights, ray_colour, le_colour, rgb;
  };
  // colour = false: only the ray token and the attention weights (no colour, no LE branch).
  Pass run_pass(const torch::Tensor& t, const Rays& rays, const torch::Tensor& ray_in, ABTransformer& ab,
                RayColourHead& ray_head, LETransformer* le_tf, LEColourHead* le_head, const torch::Tensor& le,
                const torch::Tensor& view, const torch::Tensor& view_code, bool colour, const ForwardOptions& opts);
  ModelOutput forward_serial(const Rays& rays, double near, double far, const ForwardOptions& opts);
  // forward_serial over pieces of at most kCpuPieceRays rays on a CPU when nothing is recorded for
  // autograd and nothing draws randomness (then each ray's output is what it would be in any
  // batch): a piece's tokens stay in the core's cache between the model's stages. The capture
  // preset rendering at the eval.chunk default (4096 rays): 60,300 -> 63,500 rays/s, 256-ray pieces
  // slower again (docs/benchmarks/history.md, "The grid tables' gradient formed inside Adam's update").
  ModelOutput forward_pieces(const Rays& rays, double near, double far, const ForwardOptions& opts,
                             bool draws_randomness);
  static constexpr int64_t kCpuPieceRays = 512;
  // The interval Gaussians of fence-posts t (B,N+1) (depths): contracted for unbounded scenes.
  Gaussians frustums(const torch::Tensor& t, const Rays& rays) const;
  // True when the samples' Gaussians and encoding run as kernels/sample_encoding_cpu.h (CPU float32
  // under compute.attention = "fused", nothing to differentiate through these inputs).
  bool fused_encoding(const std::vector<torch::Tensor>& inputs) const;
  torch::Tensor effective_le(const ForwardOptions& opts) const;

  ModelConfig cfg_;
  bool unbounded_ = false;
  bool ndc_ = false;
  NdcProjection ndc_projection_;
  Compute compute_;
  torch::Tensor ray_token_;                  // (1,1,E) initial ray token
  torch::Tensor mask_;                       // (S+1,S+1) additive mask buffer; undefined when model.mask is off
  torch::Tensor band_weights_;               // the IPE features' coarse-to-fine weights; undefined = none
  double band_alpha_ = -1;                   // the window band_weights_ holds
  GridEmbedding grid_{nullptr};              // model.embedding = "grid" only
  Proposal proposal_{nullptr};               // model.proposal_samples > 0 only
  PhotoColour photo_colour_{nullptr};        // train.photo_colour only
  CameraRefine camera_refine_{nullptr};      // train.camera_refine only
  AppearanceCode appearance_code_{nullptr};  // train.appearance_code only
  VolumeEmbedding volume_embedding_{nullptr};
  ABTransformer coarse_{nullptr}, fine_{nullptr};
  RayColourHead ray_head_coarse_{nullptr}, ray_head_fine_{nullptr};
  // LE branch (absent when le_count == 0).
  torch::Tensor le_;  // (1,N,E)
  torch::nn::Linear view_token_{nullptr};
  LETransformer le_coarse_{nullptr}, le_fine_{nullptr};
  LEColourHead le_head_coarse_{nullptr}, le_head_fine_{nullptr};
};
TORCH_MODULE(AbleNerf);

// Every parameter as a name -> tensor dictionary written with torch::pickle_save (readable by
// Python's torch.load). Throws InputError when the file cannot be written.
void save_weights(AbleNerf& model, const std::string& path);
// Reads save_weights' format; every parameter must be present with its exact shape and no
// other name may appear, else InputError(path, name, ...).
void load_weights(AbleNerf& model, const std::string& path);
// Reads any torch.save / pickle_save file holding a name -> tensor dictionary.
c10::Dict<c10::IValue, c10::IValue> read_weights_dict(const std::string& path);
// Copies a state dict with the authors' release names (docs/weights.md; an optional "model."
// prefix is stripped, dir_query.* is ignored) into the model. Throws InputError(origin, name,
// "expected shape ... got ..." / "missing" / "unexpected parameter") on any mismatch, before
// changing anything.
void import_release_weights(AbleNerf& model, const c10::Dict<c10::IValue, c10::IValue>& dict,
                            const std::string& origin = "weights");
// (release name, our name) for every parameter of a model with this config.
std::vector<std::pair<std::string, std::string>> release_name_map(const ModelConfig& cfg);

}  // namespace ablenerf
