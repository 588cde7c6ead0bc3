#include "model/able_nerf.h"

#include <stdexcept>

#include <ATen/CPUGeneratorImpl.h>
#include <ATen/record_function.h>

#include "kernels/cpu_parallel.h"
#include "kernels/sample_encoding_cpu.h"
#include "model/contraction.h"
#include "model/frustum.h"
#include "model/ipe.h"
#include "model/linear_tokens.h"
#include "model/resampler.h"
#include "model/tonemap.h"
#include "model/view_encoding.h"
#include "data/data_config.h"
#include "model/compute_config.h"
#include "model/model_config.h"

namespace ablenerf {

namespace {
// Seed of the LE perturbation when the caller gives no generator (same noise for every chunk).
constexpr uint64_t kLeNoiseSeed = 4;
// Added to the proposal's weights over the whole ray, 0.2 / N to each of its N (model/proposal.h):
// with weights summing to one, a sixth of the coarse samples stays spread evenly along the ray
// whatever the field says, room to find a surface it has not learned yet.
constexpr double kProposalPadding = 0.2;
static_assert(sizeof(ModelOutput) ==
                  sizeof(ModelOutput::kFields) / sizeof(ModelOutput::kFields[0]) * sizeof(torch::Tensor),
              "every ModelOutput field must be listed in ModelOutput::kFields");

// f() inside a named scope of LibTorch's profiler: the stages of the figure in `ablenerf bench
// --trace`'s operator trace (nothing is recorded when no profiler runs).
template <class F>
auto staged(const char* name, F&& f) {
  RECORD_FUNCTION(name, std::vector<c10::IValue>());
  return f();
}

// Row-wise concatenation of the outputs of consecutive ray slices (undefined fields stay so).
ModelOutput concat_outputs(const std::vector<ModelOutput>& parts) {
  const auto cat = [&](torch::Tensor ModelOutput::*field) {
    if (!(parts.front().*field).defined()) return torch::Tensor();
    std::vector<torch::Tensor> xs;
    xs.reserve(parts.size());
    for (const auto& p : parts) xs.push_back(p.*field);
    return torch::cat(xs, 0);
  };
  ModelOutput out;
  for (auto field : ModelOutput::kFields) out.*field = cat(field);
  return out;
}
}  // namespace

AbleNerfImpl::AbleNerfImpl(const ModelConfig& cfg, SceneKind scene, NdcProjection ndc)
    : cfg_(cfg),
      unbounded_(scene == SceneKind::Unbounded),
      ndc_(scene == SceneKind::ForwardFacing),
      ndc_projection_(ndc) {
  const int64_t e = cfg.width, ff = int64_t{cfg.width} * cfg.ff_ratio;
  // Plain randn (docs/MODEL.md, section 8: the release's xavier call on these is a no-op).
  ray_token_ = register_parameter("ray_token", torch::randn({1, 1, e}));
  int64_t features = ipe_width(cfg.ipe_degrees);
  if (cfg.embedding == Embedding::Grid) {
    grid_ = register_module("grid", GridEmbedding(cfg, grid_cube(cfg, scene)));
    features = grid_->width() + ipe_width(cfg.grid_ipe_degrees);
  }
  if (cfg.proposal_samples > 0) proposal_ = register_module("proposal", Proposal(cfg, grid_cube(cfg, scene)));
  volume_embedding_ = register_module("volume_embedding", VolumeEmbedding(features, e));
  coarse_ = register_module("coarse", ABTransformer(e, cfg.heads, ff, cfg.coarse_layers));
  fine_ = register_module("fine", ABTransformer(e, cfg.heads, ff, cfg.fine_layers));
  ray_head_coarse_ = register_module("ray_head_coarse", RayColourHead(e));
  ray_head_fine_ = register_module("ray_head_fine", RayColourHead(e));
  if (has_le()) {
    const int64_t view_width = view_encoding_width(cfg.view_encoding);
    le_ = register_parameter("le", torch::randn({1, cfg.le_count, e}));
    view_token_ = register_module("view_token", torch::nn::Linear(view_width, e));
    le_coarse_ = register_module("le_coarse", LETransformer(e, cfg.heads, ff, cfg.le_layers));
    le_fine_ = register_module("le_fine", LETransformer(e, cfg.heads, ff, cfg.le_layers));
    le_head_coarse_ = register_module("le_head_coarse", LEColourHead(e, view_width));
    le_head_fine_ = register_module("le_head_fine", LEColourHead(e, view_width));
  }
  if (cfg.mask) mask_ = register_buffer("ray_mask", ray_attention_mask(cfg.samples));
}

void AbleNerfImpl::set_compute(const Compute& c) {
  compute_ = c;
  for (const auto& m : modules(/*include_self=*/false))
    if (auto* attn = m->as<MultiHeadAttentionImpl>())
      attn->set_kernel(c.attention);
    else if (auto* grid = m->as<GridEmbeddingImpl>())
      grid->set_fused_inputs(c.attention == AttentionKernel::Fused);
}

void AbleNerfImpl::set_frequency_window(double alpha) {
  const bool placed = band_weights_.defined() && band_weights_.device() == ray_token_.device();
  // Unchanged (before the window's start and once it is open): no copy, which on a GPU would wait
  // for the device every step.
  if (placed && alpha == band_alpha_) return;
  const auto w = frequency_window_weights(alpha, ipe_bands());
  if (placed)
    band_weights_.copy_(w);
  else
    band_weights_ = w.to(ray_token_.device());
  band_alpha_ = alpha;
}

int64_t AbleNerfImpl::cpu_ray_workers(int64_t rays, bool draws_randomness) const {
  if (!ray_token_.device().is_cpu() || compute_.cpu_split != CpuSplit::Rays || draws_randomness) return 1;
  return ray_workers(rays);
}

namespace {
// The per-photo modules' names (their parameters' prefixes in weights files).
constexpr const char* kPhotoColourModule = "photo_colour";
constexpr const char* kCameraRefineModule = "camera_refine";
constexpr const char* kAppearanceCodeModule = "appearance_code";
}  // namespace

bool AbleNerfImpl::per_photo_parameter(const std::string& name) {
  for (const std::string module : {kPhotoColourModule, kCameraRefineModule, kAppearanceCodeModule})
    if (name.rfind(module + ".", 0) == 0) return true;
  return false;
}

void AbleNerfImpl::enable_photo_colour(int64_t photos, PhotoColourMap map) {
  if (photo_colour_) throw std::logic_error("AbleNerf: per-photo colour enabled twice");
  const auto device = ray_token_.device();
  photo_colour_ = register_module(kPhotoColourModule, PhotoColour(photos, map));
  photo_colour_->to(device);
}

void AbleNerfImpl::enable_camera_refine(int64_t cameras, bool focal) {
  if (camera_refine_) throw std::logic_error("AbleNerf: camera refinement enabled twice");
  const auto device = ray_token_.device();
  camera_refine_ =
      register_module(kCameraRefineModule, CameraRefine(cameras, kCameraRefineLrScale, /*centred=*/true, focal));
  camera_refine_->to(device);
}

void AbleNerfImpl::enable_appearance_code(int64_t photos) {
  if (appearance_code_) throw std::logic_error("AbleNerf: appearance codes enabled twice");
  if (!has_le())
    throw std::invalid_argument("appearance codes enter through the view token: the model needs model.le_count > 0");
  const auto device = ray_token_.device();
  appearance_code_ = register_module(kAppearanceCodeModule, AppearanceCode(photos, cfg_.width));
  appearance_code_->to(device);
}

std::vector<GridEmbeddingImpl*> AbleNerfImpl::grids() {
  std::vector<GridEmbeddingImpl*> out;
  if (grid_) out.push_back(grid_.get());
  if (proposal_) out.push_back(&proposal_->grid());
  return out;
}

int64_t AbleNerfImpl::parameter_count() const {
  int64_t n = 0;
  for (const auto& p : parameters()) n += p.numel();
  return n;
}

torch::Tensor AbleNerfImpl::effective_le(const ForwardOptions& opts) const {
  auto le = opts.le_zero ? torch::zeros_like(le_) : le_;
  if (opts.le_noise > 0) {
    torch::Tensor noise;
    if (opts.generator) {
      noise = torch::randn(le_.sizes(), *opts.generator, le_.options().device(opts.generator->device()));
    } else {
      auto gen = at::detail::createCPUGenerator(kLeNoiseSeed);
      noise = torch::randn(le_.sizes(), gen, le_.options().device(torch::kCPU));
    }
    le = le + opts.le_noise * noise.to(le_.device());
  }
  return le;
}

AbleNerfImpl::Pass AbleNerfImpl::run_pass(const torch::Tensor& t, const Rays& rays, const torch::Tensor& ray_in,
                                          ABTransformer& ab, RayColourHead& ray_head, LETransformer* le_tf,
                                          LEColourHead* le_head, const torch::Tensor& le, const torch::Tensor& view,
                                          const torch::Tensor& view_code, bool colour, const ForwardOptions& opts) {
  const int64_t b = t.size(0);
  const auto features = staged("ablenerf.embedding", [&] {
    const Gaussians g = frustums(t, rays);
    const auto ipe = [&](int64_t degrees) {
      auto f = fused_encoding({g.mean, g.cov}) ? integrated_pos_enc_cpu(g.mean, g.cov, degrees)
                                               : integrated_pos_enc(g.mean, g.cov, degrees);
      return band_weights_.defined() ? f * band_weights_ : f;
    };
    if (!grid_) return ipe(cfg_.ipe_degrees);
    if (cfg_.grid_ipe_degrees == 0) return grid_(g.mean, g.cov);
    // the grid's features beside a coarse IPE that says where the sample is
    return torch::cat({grid_(g.mean, g.cov), ipe(cfg_.grid_ipe_degrees)}, -1);
  });
  auto volumes = staged("ablenerf.volume_embedding", [&] { return volume_embedding_(features); });
  if (opts.near_gradient_distance > 0 && volumes.requires_grad())
    volumes = near_gradient_scaled(volumes, t, opts.near_gradient_distance);
  const auto tokens = torch::cat({ray_in.expand({b, 1, cfg_.width}), volumes}, 1);
  RayQueryProbe probe;
  probe.keep_graph = opts.weights_grad;
  // Without colour or without the LE branch the volume tokens of the last layer are unused (they
  // feed only the LE branch).
  const bool ray_token_only = !colour || le_tf == nullptr;
  const auto y = staged("ablenerf.ab_transformer", [&] { return ab->forward(tokens, mask_, &probe, ray_token_only); });
  Pass p;
  p.ray_token = y.select(1, 0);
  p.weights = ray_token_attention(probe);
  if (!colour) return p;
  p.ray_colour = staged("ablenerf.ray_head", [&] { return ray_head(p.ray_token); });
  if (le_tf) {
    const auto decoded = staged("ablenerf.le_transformer", [&] { return (*le_tf)(le, y.slice(1, 1), view); });
    p.le_colour = staged("ablenerf.le_head", [&] { return (*le_head)(decoded, view_code); });
  } else if (le_head) {
    // The view-dependent part without the LE: the head reads the ray token (CoarseWork::view_head).
    p.le_colour = staged("ablenerf.le_head", [&] { return (*le_head)(p.ray_token, view_code); });
  }
  p.rgb = tonemap(p.ray_colour, p.le_colour);
  return p;
}

bool AbleNerfImpl::fused_encoding(const std::vector<torch::Tensor>& inputs) const {
  return compute_.attention == AttentionKernel::Fused && sample_encoding_cpu_available(inputs);
}

Gaussians AbleNerfImpl::frustums(const torch::Tensor& t, const Rays& rays) const {
  if (fused_encoding({t, rays.origins, rays.directions, rays.radii})) {
    const SampleGaussians g = sample_gaussians_cpu(t, rays.origins, rays.directions, rays.radii, unbounded_);
    return {g.mean, g.cov};
  }
  return unbounded_ ? contract_intervals(t, rays) : cast_intervals(t, rays);
}

torch::Tensor near_gradient_scaled(torch::Tensor tokens, const torch::Tensor& fence_posts, double distance) {
  TORCH_CHECK(tokens.dim() == 3 && fence_posts.dim() == 2 && fence_posts.size(0) == tokens.size(0) &&
                  fence_posts.size(1) == tokens.size(1) + 1 && distance > 0,
              "near_gradient_scaled: tokens (B, S, width), fence-posts (B, S + 1) and a distance > 0 expected, got ",
              tokens.sizes(), ", ", fence_posts.sizes(), " and ", distance);
  const auto relative = interval_middles(fence_posts.detach()) / distance;
  const auto scale = relative.square().clamp_max(1.0).unsqueeze(-1).to(tokens.scalar_type());
  tokens.register_hook([scale](const torch::Tensor& g) { return g * scale; });
  return tokens;
}

ForwardOptions ForwardOptions::slice(int64_t lo, int64_t hi) const {
  ForwardOptions s = *this;
  if (coarse_jitter.defined()) s.coarse_jitter = coarse_jitter.slice(0, lo, hi);
  if (fine_jitter.defined()) s.fine_jitter = fine_jitter.slice(0, lo, hi);
  if (appearance.defined() && appearance.size(0) > 1) s.appearance = appearance.slice(0, lo, hi);
  return s;
}

ForwardOptions AbleNerfImpl::with_jitter(int64_t rays, ForwardOptions opts) const {
  if (!cfg_.randomized || !is_training() || opts.coarse_jitter.defined()) return opts;
  const auto options = ray_token_.options();
  opts.coarse_jitter = uniform_like({rays, cfg_.samples + 1}, opts.generator, options);
  opts.fine_jitter = uniform_like({rays, cfg_.samples + 1}, opts.generator, options);
  return opts;
}

ModelOutput AbleNerfImpl::forward(const Rays& in, double near, double far, const ForwardOptions& given) {
  const ForwardOptions opts = with_jitter(in.size(), given);
  // Ray-parallel on the CPU when nothing is recorded for autograd and no generator draws LE noise
  // (its draws would depend on the split); rays never interact inside the model.
  const bool draws_randomness = opts.generator != nullptr && opts.le_noise > 0;
  const int64_t workers = torch::GradMode::is_enabled() ? 1 : cpu_ray_workers(in.size(), draws_randomness);
  if (workers == 1) return forward_pieces(in, near, far, opts, draws_randomness);
  std::vector<ModelOutput> parts(static_cast<size_t>(workers));
  parallel_slices(in.size(), workers, [&](int64_t w, int64_t lo, int64_t hi) {
    parts[static_cast<size_t>(w)] = forward_pieces(in.slice(lo, hi), near, far, opts.slice(lo, hi), draws_randomness);
  });
  return concat_outputs(parts);
}

ModelOutput AbleNerfImpl::forward_pieces(const Rays& in, double near, double far, const ForwardOptions& opts,
                                         bool draws_randomness) {
  const int64_t n = in.size();
  if (torch::GradMode::is_enabled() || draws_randomness || !ray_token_.device().is_cpu() || n <= kCpuPieceRays)
    return forward_serial(in, near, far, opts);
  std::vector<ModelOutput> parts;
  for (int64_t lo = 0; lo < n; lo += kCpuPieceRays) {
    const int64_t hi = std::min(n, lo + kCpuPieceRays);
    parts.push_back(forward_serial(in.slice(lo, hi), near, far, opts.slice(lo, hi)));
  }
  return concat_outputs(parts);
}

ModelOutput AbleNerfImpl::forward_serial(const Rays& in, double near, double far, const ForwardOptions& opts) {
  const auto options = ray_token_.options();
  const Rays world{in.origins.to(options), in.directions.to(options), in.radii.to(options)};
  // Forward-facing scenes sample along the NDC ray; the view direction stays the world one.
  const Rays rays = ndc_ ? rays_to_ndc(world, ndc_projection_) : world;
  const int64_t b = rays.size();
  const AutocastScope autocast(compute_.precision, ray_token_.device());

  torch::Tensor le, view, view_code;
  if (has_le()) {
    le = effective_le(opts);
    view_code = encode_view(world.directions, cfg_.view_encoding);
    view = linear_tokens(view_token_, view_code);
    // The photo's appearance code on the view token (model/appearance_code.h).
    if (opts.appearance.defined()) view = view + opts.appearance.to(view.device(), view.scalar_type());
  }
  const bool coarse_le = has_le() && opts.coarse.le;  // the coarse colour with its LE branch
  LETransformer* le_c = coarse_le ? &le_coarse_ : nullptr;
  LETransformer* le_f = has_le() ? &le_fine_ : nullptr;
  LEColourHead* head_c = coarse_le || (has_le() && opts.coarse.view_head) ? &le_head_coarse_ : nullptr;
  LEColourHead* head_f = has_le() ? &le_head_fine_ : nullptr;

  // Unbounded scenes place and resample their fence-posts in the normalised s in [0, 1]
  // (model/contraction.h); bounded ones directly in depth.
  const auto depths = [&](const torch::Tensor& s) { return unbounded_ ? unbounded_depths(s, near, far) : s; };
  torch::Tensor s_c, proposal_s, proposal_w;
  const bool fused_pdf = compute_.attention == AttentionKernel::Fused;  // kernels/sample_pdf_cpu.h where it runs
  if (proposal_) {
    // Proposal sampling (model/proposal.h): the field's weights over even intervals of the
    // normalised ray coordinate, and the coarse fence-posts drawn from them.
    proposal_s = coarse_fence_posts(b, 0.0, 1.0, proposal_->samples(), options);
    const auto s_p = unbounded_ ? proposal_s : near + (far - near) * proposal_s;
    // On the rays detached: the proposal only places samples, so its loss must not move the
    // cameras that camera refinement corrects (model/camera_refine.h).
    const Rays fixed{rays.origins.detach(), rays.directions.detach(), rays.radii.detach()};
    proposal_w = staged("ablenerf.proposal",
                        [&] { return density_weights(proposal_->density(frustums(depths(s_p), fixed)), proposal_s); });
    const auto s_unit =
        proposal_fence_posts(proposal_s, proposal_w, cfg_.samples, kProposalPadding, opts.coarse_jitter, fused_pdf);
    s_c = unbounded_ ? s_unit : near + (far - near) * s_unit;
  } else {
    s_c = unbounded_ ? coarse_fence_posts(b, 0.0, 1.0, cfg_.samples, options, opts.coarse_jitter)
                     : coarse_fence_posts(b, near, far, cfg_.samples, options, opts.coarse_jitter);
  }
  const auto t_c = depths(s_c);
  const auto c = run_pass(t_c, rays, ray_token_, coarse_, ray_head_coarse_, le_c, head_c, le, view, view_code,
                          opts.coarse.colour, opts);
  // The inverse CDF always runs in fp32 (under bf16 autocast the weights may come back in bf16).
  const auto s_f = resample_fence_posts(s_c, c.weights.detach().to(torch::kFloat), cfg_.resample_padding,
                                        opts.fine_jitter, fused_pdf);
  const auto t_f = depths(s_f);
  // The fine ray token is the coarse output token, not detached (docs/MODEL.md, section 5).
  const auto f = run_pass(t_f, rays, c.ray_token.unsqueeze(1), fine_, ray_head_fine_, le_f, head_f, le, view, view_code,
                          /*colour=*/true, opts);

  // Outputs in fp32 whatever the precision of the products (no-ops in fp32).
  const auto fp32 = [](const torch::Tensor& x) { return x.defined() ? x.to(torch::kFloat) : x; };
  ModelOutput out;
  out.rgb_coarse = fp32(c.rgb);
  out.rgb_fine = fp32(f.rgb);
  out.coarse_weights = fp32(c.weights);
  out.fine_weights = fp32(f.weights);
  out.fine_t = t_f;
  out.fine_s = unbounded_ ? s_f : (s_f - near) / (far - near);
  out.proposal_s = proposal_s;
  out.proposal_weights = proposal_w;
  if (opts.branches) {
    out.ray_colour_coarse = fp32(c.ray_colour);
    out.ray_colour_fine = fp32(f.ray_colour);
    out.le_colour_coarse =
        c.le_colour.defined() || !opts.coarse.colour ? fp32(c.le_colour) : torch::zeros_like(out.ray_colour_coarse);
    out.le_colour_fine = has_le() ? fp32(f.le_colour) : torch::zeros_like(out.ray_colour_fine);
  }
  return out;
}

}  // namespace ablenerf
