#pragma once
// The analytic FLOP count of the model's matrix products per ray (`ablenerf bench` turns it into
// achieved FLOP/s and a share of the measured peak; docs/BENCHMARKS.md).
#include "model/coarse_work.h"
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
// The coarse pass's work as the forward does it (model/coarse_work.h). Where it computes no LE
// transformer, its last layer computes the ray token's row alone, as every pass of a model without
// LE does.
FlopCount model_flops_per_ray(const ModelConfig& cfg, const CoarseWork& coarse = {});

}  // namespace ablenerf
