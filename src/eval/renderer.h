#pragma once
// Whole-image rendering with a trained model: rays are generated and pushed through the model
// one chunk at a time (no gradient), so memory is bounded by the chunk, not the image.
// Also the depth maps read off the fine ray-token attention (docs/MODEL.md, section 9: no code in the release;
// depth = attention-weighted mean of the fine interval mid-points, or the argmax volume).
#include <torch/torch.h>

#include <cstdint>
#include <functional>

#include "data/rays.h"
#include "model/able_nerf.h"

namespace ablenerf {

struct RenderResult {
  torch::Tensor rgb;           // (H,W,3) fine colour, sRGB in [0,1]
  torch::Tensor depth_mean;    // (H,W) sum_i w_i tmid_i / sum_i w_i over the fine volumes
  torch::Tensor depth_argmax;  // (H,W) mid-point of the most-attended fine volume
  torch::Tensor depth_front;   // (H,W) the fine attention's front (AttentionDepth): the surface
  torch::Tensor depth_median;  // (H,W) the fine attention's median (AttentionDepth)
  // With ForwardOptions::branches: the fine branch colours before tone mapping (linear, not
  // clipped); undefined otherwise.
  torch::Tensor ray_colour, le_colour;  // (H,W,3)
};

// Depth maps from one batch of rays. weights: (B,S) attention over the S fine volumes (need not
// sum to one: the ray token also attends to itself); t: (B,S+1) fence-posts, interval i being
// [t_i, t_i+1].
struct AttentionDepth {
  torch::Tensor mean;    // (B)
  torch::Tensor argmax;  // (B)
  // (B) the attention's front: where the normalised attention's cumulative sum reaches
  // kAttentionFrontShare, the attention taken as constant inside each interval (so linear between
  // fence-posts). Under the causal mask every volume token at or behind the first surface has seen
  // it (docs/MODEL.md, section 4), so the ray token's attention lies at and behind the surface and
  // its front edge, not its mean, is where the surface is (docs/MODEL.md, section 9).
  torch::Tensor front;
  // (B) where half of it lies nearer (the median); with the front, how concentrated it is.
  torch::Tensor median;
};
// The share of the attention in front of the surface: measured on the demo scene's exact depth,
// 0.15 gave the least error across an IPE and a grid model (docs/benchmarks/history.md, "Depth from the
// attention's front").
constexpr double kAttentionFrontShare = 0.15;
AttentionDepth depth_from_attention(const torch::Tensor& weights, const torch::Tensor& t);

// Where the normalised attention's cumulative sum reaches `share` (in (0, 1)), linearly inside the
// interval that crosses it: (B).
torch::Tensor depth_at_attention_share(const torch::Tensor& weights, const torch::Tensor& t, double share);

// Called after each chunk with (rays done, rays total).
using RenderProgress = std::function<void(int64_t done, int64_t total)>;

// Renders every pixel of a (3,4) or (4,4) camera-to-world pose (OpenGL axes) with `chunk`
// rays per forward call. The model is used as is (call eval() first for deterministic output).
// If opts.generator is set, every chunk uses a copy of it in its starting state, so that a
// random LE perturbation is the same for the whole image and independent of `chunk`; the
// caller's generator is left untouched. Results are float32 on the CPU.
RenderResult render_image(AbleNerf& model, const torch::Tensor& c2w, const Intrinsics& k, double near, double far,
                          int64_t chunk, const ForwardOptions& opts, const torch::Device& device,
                          const RenderProgress& progress = {});

}  // namespace ablenerf
