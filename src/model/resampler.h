#pragma once
// Stage 5 (docs/MODEL.md, sections 1 and 5): where along each ray the tokens sit. Coarse fence-posts are linear
// in depth (optionally mip-NeRF jittered); fine fence-posts are drawn by inverse-CDF sampling
// from the last coarse layer's ray-token attention, blurred and padded, without gradient.
#include <torch/torch.h>

#include "model/attention.h"

namespace ablenerf {

// Uniform [0,1) numbers on options' device; drawn from `gen` (on its own device) when given.
torch::Tensor uniform_like(at::IntArrayRef sizes, torch::Generator* gen, const torch::TensorOptions& options);

// (rays, samples+1) fence-posts near + (far-near) k/samples. With `jitter` (uniform [0,1) numbers,
// (rays, samples+1), e.g. from uniform_like) each post moves to lower + u (upper - lower) between
// the mid-points to its left and right (ends clamped to near/far); undefined = the fixed grid.
torch::Tensor coarse_fence_posts(int64_t rays, double near, double far, int64_t samples,
                                 const torch::TensorOptions& options, const torch::Tensor& jitter = {});

// softmax(q0 K^T / sqrt(dh)) per head from the probe, mean over heads, column 0 (the ray token
// itself) dropped: (B,S). Not renormalised (the PDF step normalises). No gradient unless the probe
// keeps its graph (RayQueryProbe::keep_graph).
torch::Tensor ray_token_attention(const RayQueryProbe& probe);

// mip-NeRF blur-pool: pad with the end values, max of adjacent pairs, mean of adjacent pairs,
// then + padding. (B,S) -> (B,S).
torch::Tensor blur_weights(const torch::Tensor& weights, double padding);

// Piecewise-constant inverse-CDF sampling of `count` sorted values from bins (B,S+1) with
// weights (B,S). u = linspace(0, 1 - eps_f32), or stratified (u_k = (k + jitter_k (1 - eps)) / count)
// with `jitter`: uniform [0,1) numbers (B,count). `fused`: through kernels/sample_pdf_cpu.h where it
// takes the tensors (compute.attention = "fused"); these LibTorch ops are its reference.
torch::Tensor sample_pdf(const torch::Tensor& bins, const torch::Tensor& weights, int64_t count,
                         const torch::Tensor& jitter = {}, bool fused = false);

// The whole fine resampling step (no gradient): blur + pad the attention weights and draw
// S+1 new fence-posts from the coarse ones. t: (B,S+1), weights: (B,S).
torch::Tensor resample_fence_posts(const torch::Tensor& t, const torch::Tensor& weights, double padding,
                                   const torch::Tensor& jitter = {}, bool fused = false);

}  // namespace ablenerf
