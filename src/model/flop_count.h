#pragma once
// The analytic FLOP count of the model's matrix products per ray (`ablenerf bench` turns it into
// achieved FLOP/s and a share of the measured peak; docs/BENCHMARKS.md).
#include "model/model_config.h"

namespace ablenerf {

// Two floating-point operations per multiply-add.
constexpr double kFlopPerMac = 2.0;

// Floating-point operations per ray of the matrix products the model runs (dense GEMMs,
// attention scores and attention-weighted sums; 2 FLOP per multiply-add). Element-wise work
// (IPE, softmax, LayerNorm, GELU, resampling) is not counted. The LE query projection, computed
// once per forward call for the whole batch, is not a per-ray cost and is left out. The volume
// embedding is counted as the paper's IPE MLP (model.embedding = "ipe").
struct FlopCount {
  double forward = 0;   // inference forward
  double backward = 0;  // gradients of a training step (no-grad products excluded)
  double train() const { return forward + backward; }
};
// What the coarse pass computes beside its attention and ray token (ForwardOptions::coarse_colour,
// coarse_le, coarse_view_head). Where it computes no LE transformer, its last layer computes the ray
// token's row alone, as every pass of a model without LE does.
struct CoarseWork {
  bool colour = true;      // the coarse colour at all (false when rendering, or train.coarse_weight = 0)
  bool le = true;          // ... with the coarse LE transformer (the paper)
  bool view_head = false;  // ... or, without it, the LE colour head on the ray token
};
FlopCount model_flops_per_ray(const ModelConfig& cfg, const CoarseWork& coarse = {});

}  // namespace ablenerf
