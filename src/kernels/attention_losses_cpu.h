#pragma once
// The training step's losses on the ray token's attention, in one autograd node on the CPU: the
// proposal loss in its two roles and the distortion loss, all of them read off the attention as a
// distribution a = w / max(sum w, 1e-6) (train/regularisers.h, attention_distribution):
//   proposal      sum_rays proposal_loss(s_p, w_p, s_t, a)   gradient to w_p only (a held fixed)
//   attention     the same value                              gradient to w only (w_p held fixed)
//   distortion    sum_rays distortion_loss(a, s_t)            gradient to w
// Why: written with LibTorch ops these are about 120 small ops and as many autograd nodes per ray
// slice (prefix sums, searchsorted, gathers, clamps), on a few hundred numbers each: at 256 rays on
// 2 cores their dispatch cost more than the arithmetic. Here each ray is one loop, forward and
// backward. The plain reference is train/regularisers.h's functions (the tests compare them, and
// compute.attention = "plain" trains through them).
#include <torch/torch.h>

namespace ablenerf {

struct AttentionLosses {
  // 0-d sums over the rays, in w's dtype; undefined where not asked for.
  torch::Tensor proposal, attention, distortion;
};

// True when attention_losses_cpu can take these: CPU tensors of one floating dtype (float32 or
// float64), w (B,M), s_t (B,M+1), s_p (B,N+1), w_p (B,N), the fence-posts without a gradient of their
// own. The proposal's inputs may be undefined (no proposal field).
bool attention_losses_cpu_available(const torch::Tensor& w, const torch::Tensor& s_t, const torch::Tensor& s_p,
                                    const torch::Tensor& w_p);

// The terms asked for (`proposal`, `distortion`: which to compute; with `proposal` both proposal roles).
// Fence-posts sorted along each ray. Bad shapes or dtypes: a c10::Error naming attention_losses_cpu
// and the argument.
AttentionLosses attention_losses_cpu(const torch::Tensor& w, const torch::Tensor& s_t, const torch::Tensor& s_p,
                                     const torch::Tensor& w_p, bool proposal, bool distortion);

}  // namespace ablenerf
