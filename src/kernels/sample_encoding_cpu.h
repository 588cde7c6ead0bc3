#pragma once
// The samples' Gaussians, their integrated positional encoding (docs/MODEL.md, sections 1-2) and
// what the grid front end reads of them, as loops over the samples of a ray slice (CPU, float32,
// no autograd):
//
//   sample_gaussians_cpu:     fence posts t (B, S+1) and rays -> each interval's conical frustum
//                             as a Gaussian, mean and diagonal covariance (B, S, 3); with `contract`
//                             both pass through the scene contraction (mean contracted, covariance
//                             through the contraction's Jacobian)
//   integrated_pos_enc_cpu:   mean, cov (..., 3) -> (..., 6 degrees): exp(-v/2) sin(y) for the
//                             sines, then exp(-v/2) sin(y + pi/2) for the cosines
//   grid_inputs_cpu:          mean, cov (..., 3) -> the points in the grid cube's unit coordinates
//                             (N, 3) and each level's weight (N, L): erf(1 / sqrt(8 sigma2 n^2))
//                             times a scale inside the cube, 0 outside (model/grid_embedding.h)
//
// Why: written with tensor ops these are ~70 element-wise operations per pass over (B, S, 3)
// tensors of a few thousand samples, each paying a dispatch and a trip through memory; on a 2-core
// training step the embedding's and the proposal's stages dispatched 750 of the 1,340 operations of
// a thread's forward, 120 with these loops (docs/benchmarks/history.md, "Row loops in vectors"). Here each sample is
// computed in registers, the sines and exponentials of a block of samples by Sleef's vector functions (AVX-512).
//
// Their plain reference is the model's own stage functions, which compute the same formulas with
// LibTorch ops and which `compute.attention = "plain"` runs: model/frustum.h (cast_intervals),
// model/contraction.h (contract_intervals), model/ipe.h and model/grid_embedding.h;
// tests/model/sample_encoding_test.cpp compares the two. Used only where no gradient flows through the samples (without
// camera refinement the rays and fence posts are constants of the step).
#include <torch/torch.h>

#include "kernels/cpu_features.h"

namespace ablenerf {

// Shared with the plain path (model/frustum.cpp, model/contraction.cpp): the directions' squared
// norm is offset by this in the perpendicular projector (the release's constant, which keeps it
// finite for a zero direction), and radii are clamped to this before the contraction divides by them.
constexpr double kFrustumDirNormEps = 1e-10;
constexpr double kContractRadiusEps = 1e-12;

// True when the loops below run on these inputs: CPU float32 tensors, nothing that autograd would
// have to differentiate, and a CPU with AVX-512 (elsewhere LibTorch's own vectorised ops are faster
// than the scalar form of these loops).
bool sample_encoding_cpu_available(const std::vector<torch::Tensor>& inputs);

struct SampleGaussians {
  torch::Tensor mean, cov;  // (B, S, 3)
};

// t: (B, S+1) fence posts along each ray; origins, directions: (B, 3); radii: (B, 1). Throws
// c10::Error naming "sample_gaussians_cpu" and the argument on a bad shape, dtype or device.
SampleGaussians sample_gaussians_cpu(const torch::Tensor& t, const torch::Tensor& origins,
                                     const torch::Tensor& directions, const torch::Tensor& radii, bool contract);

// mean, cov: (..., 3) of the same shape; degrees >= 1. `form`: the sines' and exponentials' vector
// form (Scalar: the C library's functions; the tests run each form this CPU has). Throws c10::Error
// naming "integrated_pos_enc_cpu" on a bad shape, dtype or device, or a form this CPU lacks.
torch::Tensor integrated_pos_enc_cpu(const torch::Tensor& mean, const torch::Tensor& cov, int64_t degrees,
                                     CpuVectorForm form = cpu_best_vector_form());

struct GridInputs {
  torch::Tensor unit, weights;  // (N, 3), (N, L)
  torch::Tensor inside;         // (N): 1 where the point lies in the cube (faces included), else 0
};

// mean, cov: (..., 3) of the same shape (N points); the grid's cube [lo, hi]^3; resolution: (L)
// cells per side; every weight multiplied by `scale`. sigma2 is the mean of cov's three variances
// over the cube's side squared. The vector form evaluates erf from Sleef's exp by Abramowitz and
// Stegun 7.1.26 (absolute error under 1.5e-7, as kernels/gelu_cpu.h). Throws c10::Error naming
// "grid_inputs_cpu" on a bad shape, dtype or device, or a form this CPU or build lacks.
GridInputs grid_inputs_cpu(const torch::Tensor& mean, const torch::Tensor& cov, double lo, double hi,
                           const torch::Tensor& resolution, double scale, CpuVectorForm form = cpu_best_vector_form());

}  // namespace ablenerf
