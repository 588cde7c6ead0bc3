#include "model/resampler.h"

#include <cmath>
#include <limits>

#include "kernels/sample_pdf_cpu.h"
#include "model/frustum.h"

namespace ablenerf {

namespace {
// mip-NeRF's floor on the total weight (pads all-zero rays into a uniform PDF).
constexpr double kMinWeightSum = 1e-5;
// CDF steps narrower than this are treated as width 1 (avoids 0/0 in empty bins).
constexpr double kMinCdfStep = 1e-5;
// The largest u is 1 - float32 epsilon so that searchsorted never runs off the last bin.
constexpr double kUnitEps = std::numeric_limits<float>::epsilon();
}  // namespace

torch::Tensor uniform_like(at::IntArrayRef sizes, torch::Generator* gen, const torch::TensorOptions& options) {
  if (!gen) return torch::rand(sizes, options);
  return torch::rand(sizes, *gen, options.device(gen->device())).to(options.device());
}

torch::Tensor coarse_fence_posts(int64_t rays, double near, double far, int64_t samples,
                                 const torch::TensorOptions& options, const torch::Tensor& jitter) {
  auto t = torch::linspace(near, far, samples + 1, options).unsqueeze(0).expand({rays, samples + 1});
  if (!jitter.defined()) return t;
  TORCH_CHECK(jitter.dim() == 2 && jitter.size(0) == rays && jitter.size(1) == samples + 1,
              "coarse_fence_posts: jitter must be (rays, samples+1)");
  const auto mids = interval_middles(t);
  const auto upper = torch::cat({mids, t.slice(1, samples)}, 1);
  const auto lower = torch::cat({t.slice(1, 0, 1), mids}, 1);
  return lower + (upper - lower) * jitter.to(options);
}

torch::Tensor ray_token_attention(const RayQueryProbe& probe) {
  // Without keep_graph the row is a by-product for the resampler and depth: no graph is built.
  c10::optional<torch::NoGradGuard> no_grad;
  if (!probe.keep_graph) no_grad.emplace();
  if (probe.row0.defined()) return probe.row0.mean(1).slice(1, 1);
  const double scale = 1.0 / std::sqrt(static_cast<double>(probe.k.size(-1)));
  // (B,H,L,dh) . (B,H,1,dh) -> (B,H,L): the ray token is unmasked, so no mask is needed. A
  // broadcast product and a sum over dh, not a matmul: that would copy the strided keys and run
  // one tiny product per ray and head (on 2 CPU cores it took ~5% of a demo-size training step).
  const auto scores = (probe.k * probe.q0.unsqueeze(2)).sum(-1) * scale;
  return torch::softmax(scores, -1).mean(1).slice(1, 1);
}

torch::Tensor blur_weights(const torch::Tensor& w, double padding) {
  const int64_t s = w.size(-1);
  const auto padded = torch::cat({w.slice(-1, 0, 1), w, w.slice(-1, s - 1)}, -1);      // S+2
  const auto maxed = torch::maximum(padded.slice(-1, 0, s + 1), padded.slice(-1, 1));  // S+1
  return 0.5 * (maxed.slice(-1, 0, s) + maxed.slice(-1, 1)) + padding;                 // S
}

torch::Tensor sample_pdf(const torch::Tensor& bins, const torch::Tensor& weights, int64_t count,
                         const torch::Tensor& jitter, bool fused) {
  if (fused && sample_pdf_cpu_available(bins, weights, jitter))
    return sample_pdf_cpu(bins, weights, count, jitter, {kMinWeightSum, kMinCdfStep, kUnitEps});
  const int64_t s = weights.size(-1), b = weights.size(0);
  auto sum = weights.sum(-1, /*keepdim=*/true);
  const auto pad = torch::clamp_min(kMinWeightSum - sum, 0.0);
  const auto pdf = (weights + pad / s) / (sum + pad);
  const auto inner = torch::clamp_max(torch::cumsum(pdf.slice(-1, 0, s - 1), -1), 1.0);
  const auto cdf = torch::cat({torch::zeros({b, 1}, pdf.options()), inner, torch::ones({b, 1}, pdf.options())}, -1);

  torch::Tensor u;
  if (jitter.defined()) {
    TORCH_CHECK(jitter.dim() == 2 && jitter.size(0) == b && jitter.size(1) == count,
                "sample_pdf: jitter must be (B, count)");
    const double step = 1.0 / count;
    u = torch::arange(count, cdf.options()) * step + jitter.to(cdf.options()) * (step - kUnitEps);
    u = torch::clamp_max(u, 1.0 - kUnitEps);
  } else {
    u = torch::linspace(0.0, 1.0 - kUnitEps, count, cdf.options()).expand({b, count}).contiguous();
  }
  const auto idx = torch::searchsorted(cdf, u, /*out_int32=*/false, /*right=*/true);
  const auto below = torch::clamp_min(idx - 1, 0), above = torch::clamp_max(idx, s);
  const auto cdf0 = cdf.gather(-1, below), cdf1 = cdf.gather(-1, above);
  const auto bin0 = bins.gather(-1, below), bin1 = bins.gather(-1, above);
  auto denom = cdf1 - cdf0;
  denom = torch::where(denom < kMinCdfStep, torch::ones_like(denom), denom);
  return bin0 + (u - cdf0) / denom * (bin1 - bin0);
}

torch::Tensor resample_fence_posts(const torch::Tensor& t, const torch::Tensor& weights, double padding,
                                   const torch::Tensor& jitter, bool fused) {
  torch::NoGradGuard no_grad;
  return sample_pdf(t.contiguous(), blur_weights(weights, padding), t.size(-1), jitter, fused);
}

}  // namespace ablenerf
