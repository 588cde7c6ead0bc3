#include "kernels/sample_pdf_cpu.h"

#include <algorithm>
#include <vector>

#include "kernels/cpu_features.h"

namespace ablenerf {

namespace {

// ATen's float linspace: the first half counted up from the start, the second down from the end.
float linspace_value(float start, float end, int64_t steps, int64_t i) {
  if (steps == 1) return start;
  const float step = (end - start) / static_cast<float>(steps - 1);
  const int64_t halfway = steps / 2;
  return i < halfway ? start + step * static_cast<float>(i) : end - step * static_cast<float>(steps - i - 1);
}

// One ray: its CDF over S bins, then each u located by a forward scan (the u rise along the row)
// and interpolated within its bin, each operation rounded to float32 as the reference's ops are.
ABLENERF_SEPARATE_ROUNDINGS void sample_row(const float* bins, const float* w, int64_t s, int64_t count,
                                            const float* jitter, const SamplePdfConstants& k, float* cdf, float* out) {
  double sum_d = 0;
  for (int64_t i = 0; i < s; ++i) sum_d += w[i];
  const float sum = static_cast<float>(sum_d);
  const float pad = std::max(static_cast<float>(k.min_weight_sum) - sum, 0.f);
  const float pad_each = pad / static_cast<float>(s), total = sum + pad;
  cdf[0] = 0.f;
  double acc = 0;
  for (int64_t i = 0; i + 1 < s; ++i) {
    acc += static_cast<double>((w[i] + pad_each) / total);
    cdf[i + 1] = std::min(static_cast<float>(acc), 1.f);
  }
  cdf[s] = 1.f;
  const float last = static_cast<float>(1.0 - k.unit_eps);
  const float step = static_cast<float>(1.0 / static_cast<double>(count));
  const float jitter_step = static_cast<float>(1.0 / static_cast<double>(count) - k.unit_eps);
  const float min_step = static_cast<float>(k.min_cdf_step);
  int64_t idx = 0;
  float previous = -1.f;
  for (int64_t j = 0; j < count; ++j) {
    float u;
    if (jitter != nullptr) {
      const float base = static_cast<float>(j) * step, offset = jitter[j] * jitter_step;
      u = std::min(base + offset, last);
    } else {
      u = linspace_value(0.f, last, count, j);
    }
    if (!(u >= previous)) idx = 0;  // only rising u continue the scan
    previous = u;
    // searchsorted(right): the number of CDF entries <= u.
    while (idx <= s && cdf[idx] <= u) ++idx;
    const int64_t below = std::max<int64_t>(idx - 1, 0), above = std::min(idx, s);
    const float c0 = cdf[below], c1 = cdf[above];
    float denom = c1 - c0;
    if (denom < min_step) denom = 1.f;
    const float t = (u - c0) / denom;
    out[j] = bins[below] + t * (bins[above] - bins[below]);
  }
}

}  // namespace

bool sample_pdf_cpu_available(const torch::Tensor& bins, const torch::Tensor& weights, const torch::Tensor& jitter) {
  const auto ok = [](const torch::Tensor& t) {
    return t.device().is_cpu() && t.scalar_type() == torch::kFloat && t.is_contiguous() && t.dim() == 2 &&
           !t.requires_grad();
  };
  return ok(bins) && ok(weights) && (!jitter.defined() || ok(jitter)) && weights.size(-1) >= 1 &&
         bins.size(-1) == weights.size(-1) + 1 && bins.size(0) == weights.size(0);
}

torch::Tensor sample_pdf_cpu(const torch::Tensor& bins, const torch::Tensor& weights, int64_t count,
                             const torch::Tensor& jitter, const SamplePdfConstants& k) {
  TORCH_CHECK(weights.dim() == 2 && weights.size(1) >= 1, "sample_pdf_cpu: weights must be (B, S) with S >= 1");
  const int64_t b = weights.size(0), s = weights.size(1);
  TORCH_CHECK(bins.dim() == 2 && bins.size(0) == b && bins.size(1) == s + 1, "sample_pdf_cpu: bins must be (B, S+1)");
  TORCH_CHECK(count >= 1, "sample_pdf_cpu: count must be >= 1");
  TORCH_CHECK(!jitter.defined() || (jitter.dim() == 2 && jitter.size(0) == b && jitter.size(1) == count),
              "sample_pdf_cpu: jitter must be (B, count)");
  TORCH_CHECK(sample_pdf_cpu_available(bins, weights, jitter),
              "sample_pdf_cpu: bins, weights and jitter must be contiguous float32 CPU tensors without gradients");
  auto out = torch::empty({b, count}, weights.options());
  const float *pb = bins.data_ptr<float>(), *pw = weights.data_ptr<float>();
  const float* pj = jitter.defined() ? jitter.data_ptr<float>() : nullptr;
  float* po = out.data_ptr<float>();
  std::vector<float> cdf(static_cast<size_t>(s + 1));
  for (int64_t r = 0; r < b; ++r)
    sample_row(pb + r * (s + 1), pw + r * s, s, count, pj != nullptr ? pj + r * count : nullptr, k, cdf.data(),
               po + r * count);
  return out;
}

}  // namespace ablenerf
