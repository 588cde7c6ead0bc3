#pragma once
// Piecewise-constant inverse-CDF sampling (model/resampler.h's sample_pdf: the proposal's coarse
// fence-posts and the attention-guided fine ones) as one loop per ray on the CPU. Why: written with
// LibTorch ops it is about 35 small ops per call on a few dozen numbers per ray (a sum, a prefix sum,
// searchsorted, four gathers, clamps), twice per forward; their dispatch cost more than the
// arithmetic (docs/benchmarks/history.md, "The inverse CDF in one loop"). The plain reference is
// sample_pdf itself, which compute.attention = "plain" runs; the tests compare the two. No gradient.
#include <torch/torch.h>

namespace ablenerf {

// The reference's constants, passed by its caller (model/resampler.cpp owns them).
struct SamplePdfConstants {
  double min_weight_sum;  // rows whose weights sum below it are padded towards uniform
  double min_cdf_step;    // a CDF step below it interpolates over a unit step instead
  double unit_eps;        // u stays below 1 - unit_eps
};

// True when sample_pdf_cpu takes these: contiguous float32 CPU tensors, bins (B,S+1), weights (B,S),
// jitter undefined or (B,count), no gradient asked of any.
bool sample_pdf_cpu_available(const torch::Tensor& bins, const torch::Tensor& weights, const torch::Tensor& jitter);

// `count` sorted values per row (B,count), as sample_pdf: u = linspace(0, 1 - unit_eps, count), or
// with `jitter` u_k = k / count + jitter_k (1 / count - unit_eps); the weights' sum and prefix sums
// accumulated in float64 (ATen's cumsum accumulates so; its sum in float32, so results agree to
// float32 rounding, not to the bit). Bad shapes or dtypes: a c10::Error naming sample_pdf_cpu and
// the argument.
torch::Tensor sample_pdf_cpu(const torch::Tensor& bins, const torch::Tensor& weights, int64_t count,
                             const torch::Tensor& jitter, const SamplePdfConstants& k);

}  // namespace ablenerf
