#include "kernels/sample_encoding_cpu.h"

#include <ATen/record_function.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "kernels/tensor_checks.h"

#if defined(ABLENERF_HAVE_SLEEF) && defined(ABLENERF_HAVE_AVX2_FORM)
#define ABLENERF_ENCODING_SLEEF 1
#include <immintrin.h>
// Sleef's AVX-512 sine and exponential (see kernels/gelu_cpu.cpp on why they are declared here).
#pragma GCC push_options
#pragma GCC target("avx512f,avx2,fma")
extern "C" {
__m512 Sleef_sinf16_u10avx512f(__m512);
__m512 Sleef_expf16_u10avx512f(__m512);
}
#pragma GCC pop_options
#include "kernels/erfc_approx.h"
#endif

namespace ablenerf {

// Named: the unity build compiles this file with the other kernels.
namespace sample_encoding_impl {

constexpr const char* kGaussiansOp = "sample_gaussians_cpu";
constexpr const char* kIpeOp = "integrated_pos_enc_cpu";
constexpr const char* kGridOp = "grid_inputs_cpu";
// Samples whose angles and exponentials are taken at a time (their buffers stay in L1).
constexpr int64_t kIpeBlock = 64;
constexpr float kHalfPi = float(M_PI / 2.0);

bool form_runs(CpuVectorForm form) {
#ifdef ABLENERF_ENCODING_SLEEF
  return cpu_vector_form_available(form);
#else
  return form == CpuVectorForm::Scalar;
#endif
}

// Rays [lo, hi): each interval [t_k, t_k+1] as a Gaussian, the formulas of model/frustum.cpp and
// model/contraction.cpp per sample.
void gaussians_rows(const float* t, const float* origins, const float* directions, const float* radii, int64_t s,
                    bool contract, int64_t lo, int64_t hi, float* mean, float* cov) {
  for (int64_t b = lo; b < hi; ++b) {
    const float* tb = t + b * (s + 1);
    const float* o = origins + 3 * b;
    const float* d = directions + 3 * b;
    const float r2 = radii[b] * radii[b];
    const float d2[3] = {d[0] * d[0], d[1] * d[1], d[2] * d[2]};
    const float dn = d2[0] + d2[1] + d2[2];
    for (int64_t k = 0; k < s; ++k) {
      const float mu = 0.5f * (tb[k] + tb[k + 1]), h = 0.5f * (tb[k + 1] - tb[k]);
      const float mu2 = mu * mu, h2 = h * h, denom = 3.0f * mu2 + h2;
      const float t_mean = mu + 2.0f * mu * h2 / denom;
      const float t_var = h2 / 3.0f - float(4.0 / 15.0) * (h2 * h2 * (12.0f * mu2 - h2)) / (denom * denom);
      const float r_var = r2 * (mu2 / 4.0f + float(5.0 / 12.0) * h2 - float(4.0 / 15.0) * (h2 * h2) / denom);
      float* m = mean + 3 * (b * s + k);
      float* c = cov + 3 * (b * s + k);
      for (int j = 0; j < 3; ++j) m[j] = o[j] + d[j] * t_mean;
      if (!contract) {
        for (int j = 0; j < 3; ++j) c[j] = t_var * d2[j] + r_var * (1.0f - d2[j] / (dn + float(kFrustumDirNormEps)));
        continue;
      }
      // S = a d d^T + b I through J = f I + g x x^T (model/contraction.h).
      const float a = t_var - r_var / dn;
      const float x2[3] = {m[0] * m[0], m[1] * m[1], m[2] * m[2]};
      const float r = std::max(std::sqrt(x2[0] + x2[1] + x2[2]), float(kContractRadiusEps));
      const bool outside = r > 1.0f;
      const float f = outside ? (2.0f - 1.0f / r) / r : 1.0f;
      const float g = outside ? (2.0f / (r * r * r) - 2.0f / (r * r)) / r : 0.0f;
      const float xd = m[0] * d[0] + m[1] * d[1] + m[2] * d[2];
      for (int j = 0; j < 3; ++j) {
        const float jd = f * d[j] + g * m[j] * xd;
        const float jj = f * f + 2.0f * f * g * x2[j] + g * g * x2[j] * (r * r);
        c[j] = r_var * jj + a * jd * jd;
      }
      if (outside)
        for (int j = 0; j < 3; ++j) m[j] = (2.0f - 1.0f / r) * m[j] / r;
    }
  }
}

#ifdef ABLENERF_ENCODING_SLEEF
// x[i] <- F(x[i]) over n floats, 16 at a time; the lanes past n read 1 (a harmless argument for
// every F here) and are not stored.
template <__m512 (*F)(__m512)>
__attribute__((target("avx512f"))) void map_avx512(float* x, int64_t n) {
  int64_t i = 0;
  for (; i + 16 <= n; i += 16) _mm512_storeu_ps(x + i, F(_mm512_loadu_ps(x + i)));
  if (i < n) {
    const __mmask16 k = static_cast<__mmask16>((1u << (n - i)) - 1u);
    _mm512_mask_storeu_ps(x + i, k, F(_mm512_mask_loadu_ps(_mm512_set1_ps(1.0f), k, x + i)));
  }
}
#endif

// In place over n floats: sine, and exponential.
void sin_block(float* x, int64_t n, CpuVectorForm form) {
#ifdef ABLENERF_ENCODING_SLEEF
  if (form == CpuVectorForm::Avx512) return map_avx512<Sleef_sinf16_u10avx512f>(x, n);
#endif
  for (int64_t i = 0; i < n; ++i) x[i] = std::sin(x[i]);
}

void exp_block(float* x, int64_t n, CpuVectorForm form) {
#ifdef ABLENERF_ENCODING_SLEEF
  if (form == CpuVectorForm::Avx512) return map_avx512<Sleef_expf16_u10avx512f>(x, n);
#endif
  for (int64_t i = 0; i < n; ++i) x[i] = std::exp(x[i]);
}

// Samples [0, n): the angles (sines' then cosines', 6L per sample) written into out, the
// exponents -v/2 (3L per sample) into att; both evaluated a block at a time, then multiplied.
void ipe_rows(const float* mean, const float* cov, int64_t n, int64_t degrees, CpuVectorForm form, float* out) {
  const int64_t half = 3 * degrees, width = 2 * half;
  std::vector<float> att(static_cast<size_t>(kIpeBlock * half));
  for (int64_t lo = 0; lo < n; lo += kIpeBlock) {
    const int64_t hi = std::min(n, lo + kIpeBlock);
    for (int64_t i = lo; i < hi; ++i) {
      float* row = out + i * width;
      float* a = att.data() + (i - lo) * half;
      float scale = 1.0f;  // 2^l, exact
      for (int64_t l = 0; l < degrees; ++l, scale *= 2.0f)
        for (int c = 0; c < 3; ++c) {
          const float y = mean[3 * i + c] * scale;
          row[3 * l + c] = y;
          row[half + 3 * l + c] = y + kHalfPi;
          a[3 * l + c] = -0.5f * (cov[3 * i + c] * (scale * scale));
        }
    }
    sin_block(out + lo * width, (hi - lo) * width, form);
    exp_block(att.data(), (hi - lo) * half, form);
    for (int64_t i = lo; i < hi; ++i) {
      float* row = out + i * width;
      const float* a = att.data() + (i - lo) * half;
      for (int64_t j = 0; j < half; ++j) {
        row[j] *= a[j];
        row[half + j] *= a[j];
      }
    }
  }
}

#ifdef ABLENERF_ENCODING_SLEEF
// erf(1 / sqrt(x)) for x >= 0 (x = 0 gives 1).
__attribute__((target("avx512f"))) __m512 erf_rsqrt16(__m512 x) {
  const __m512 one = _mm512_set1_ps(1.0f);
  // +inf at x = 0: t = 0, erf = 1. (The masked square root with every lane set: GCC 12's unmasked
  // form reads an undefined vector and warns.)
  const __m512 z = _mm512_div_ps(one, _mm512_mask_sqrt_ps(x, static_cast<__mmask16>(0xFFFF), x));
  const __m512 e = Sleef_expf16_u10avx512f(_mm512_sub_ps(_mm512_setzero_ps(), _mm512_div_ps(one, x)));
  return _mm512_sub_ps(one, _mm512_mul_ps(erfc_approx::factor16(z), e));  // erf = 1 - erfc (kernels/erfc_approx.h)
}

#endif

// x[i] <- erf(1 / sqrt(x[i])) in place over n floats.
void erf_rsqrt_block(float* x, int64_t n, CpuVectorForm form) {
#ifdef ABLENERF_ENCODING_SLEEF
  if (form == CpuVectorForm::Avx512) return map_avx512<erf_rsqrt16>(x, n);
#endif
  for (int64_t i = 0; i < n; ++i) x[i] = std::erf(1.0f / std::sqrt(x[i]));
}

// Points [0, n): unit coordinates, then 8 sigma2 n_l^2 per level into weights, erf(1 / sqrt(.)) of
// them a block at a time, times the scale inside the cube and 0 outside.
void grid_rows(const float* mean, const float* cov, int64_t n, float lo, float hi, const float* res, int64_t levels,
               float scale, CpuVectorForm form, float* unit, float* weights, float* inside_out) {
  const float side = hi - lo, inv_side2 = 1.0f / (side * side);
  for (int64_t i = 0; i < n; ++i) {
    for (int c = 0; c < 3; ++c) unit[3 * i + c] = (mean[3 * i + c] - lo) / side;
    const float sigma2 = (cov[3 * i] + cov[3 * i + 1] + cov[3 * i + 2]) / 3.0f * inv_side2;
    for (int64_t l = 0; l < levels; ++l) weights[i * levels + l] = 8.0f * sigma2 * (res[l] * res[l]);
  }
  erf_rsqrt_block(weights, n * levels, form);
  for (int64_t i = 0; i < n; ++i) {
    const float* u = unit + 3 * i;
    const bool inside = u[0] >= 0 && u[0] <= 1 && u[1] >= 0 && u[1] <= 1 && u[2] >= 0 && u[2] <= 1;
    inside_out[i] = inside ? 1.0f : 0.0f;
    for (int64_t l = 0; l < levels; ++l) weights[i * levels + l] = inside ? weights[i * levels + l] * scale : 0.0f;
  }
}

void check_cpu_float(const char* op, const char* name, const torch::Tensor& x) {
  TORCH_CHECK(x.defined() && x.device().is_cpu() && x.scalar_type() == torch::kFloat, op, ": ", name,
              " must be a CPU float32 tensor");
}

}  // namespace sample_encoding_impl

namespace enc = sample_encoding_impl;

bool sample_encoding_cpu_available(const std::vector<torch::Tensor>& inputs) {
  if (!enc::form_runs(CpuVectorForm::Avx512)) return false;
  const bool grad = torch::GradMode::is_enabled();
  for (const auto& x : inputs)
    if (!x.defined() || !x.device().is_cpu() || x.scalar_type() != torch::kFloat || (grad && x.requires_grad()))
      return false;
  return true;
}

SampleGaussians sample_gaussians_cpu(const torch::Tensor& t, const torch::Tensor& origins,
                                     const torch::Tensor& directions, const torch::Tensor& radii, bool contract) {
  RECORD_FUNCTION("ablenerf::sample_gaussians", std::vector<c10::IValue>());
  for (const auto& [name, x] : {std::pair<const char*, const torch::Tensor*>{"t", &t},
                                {"origins", &origins},
                                {"directions", &directions},
                                {"radii", &radii}})
    enc::check_cpu_float(enc::kGaussiansOp, name, *x);
  TORCH_CHECK(t.dim() == 2 && t.size(1) >= 2, enc::kGaussiansOp, ": t must be (B, S+1) with S >= 1, got ", t.sizes());
  const int64_t b = t.size(0), s = t.size(1) - 1;
  TORCH_CHECK(origins.dim() == 2 && origins.size(0) == b && origins.size(1) == 3, enc::kGaussiansOp,
              ": origins must be (", b, ", 3), got ", origins.sizes());
  TORCH_CHECK(directions.sizes() == origins.sizes(), enc::kGaussiansOp, ": directions must be (", b, ", 3), got ",
              directions.sizes());
  TORCH_CHECK(radii.dim() == 2 && radii.size(0) == b && radii.size(1) == 1, enc::kGaussiansOp, ": radii must be (", b,
              ", 1), got ", radii.sizes());
  const auto tc = t.contiguous(), oc = origins.contiguous(), dc = directions.contiguous(), rc = radii.contiguous();
  SampleGaussians g{torch::empty({b, s, 3}, t.options()), torch::empty({b, s, 3}, t.options())};
  enc::gaussians_rows(tc.data_ptr<float>(), oc.data_ptr<float>(), dc.data_ptr<float>(), rc.data_ptr<float>(), s,
                      contract, 0, b, g.mean.data_ptr<float>(), g.cov.data_ptr<float>());
  return g;
}

torch::Tensor integrated_pos_enc_cpu(const torch::Tensor& mean, const torch::Tensor& cov, int64_t degrees,
                                     CpuVectorForm form) {
  RECORD_FUNCTION("ablenerf::integrated_pos_enc", std::vector<c10::IValue>());
  enc::check_cpu_float(enc::kIpeOp, "mean", mean);
  enc::check_cpu_float(enc::kIpeOp, "cov", cov);
  TORCH_CHECK(mean.dim() >= 1 && mean.size(-1) == 3, enc::kIpeOp, ": mean must be (..., 3), got ", mean.sizes());
  TORCH_CHECK(cov.sizes() == mean.sizes(), enc::kIpeOp, ": cov must have mean's shape ", mean.sizes(), ", got ",
              cov.sizes());
  TORCH_CHECK(degrees >= 1, enc::kIpeOp, ": degrees must be at least 1, got ", degrees);
  TORCH_CHECK(enc::form_runs(form), enc::kIpeOp, ": this CPU or build does not run the requested form");
  auto shape = mean.sizes().vec();
  shape.back() = 6 * degrees;
  auto out = torch::empty(shape, mean.options());
  const auto mc = mean.contiguous(), cc = cov.contiguous();
  enc::ipe_rows(mc.data_ptr<float>(), cc.data_ptr<float>(), mean.numel() / 3, degrees, form, out.data_ptr<float>());
  return out;
}

GridInputs grid_inputs_cpu(const torch::Tensor& mean, const torch::Tensor& cov, double lo, double hi,
                           const torch::Tensor& resolution, double scale, CpuVectorForm form) {
  RECORD_FUNCTION("ablenerf::grid_inputs", std::vector<c10::IValue>());
  enc::check_cpu_float(enc::kGridOp, "mean", mean);
  enc::check_cpu_float(enc::kGridOp, "cov", cov);
  enc::check_cpu_float(enc::kGridOp, "resolution", resolution);
  TORCH_CHECK(mean.dim() >= 1 && mean.size(-1) == 3, enc::kGridOp, ": mean must be (..., 3), got ", mean.sizes());
  TORCH_CHECK(cov.sizes() == mean.sizes(), enc::kGridOp, ": cov must have mean's shape ", mean.sizes(), ", got ",
              cov.sizes());
  TORCH_CHECK(resolution.dim() == 1 && resolution.size(0) >= 1, enc::kGridOp, ": resolution must be (levels), got ",
              resolution.sizes());
  TORCH_CHECK(hi > lo, enc::kGridOp, ": the cube's hi must exceed its lo, got ", lo, " and ", hi);
  TORCH_CHECK(enc::form_runs(form), enc::kGridOp, ": this CPU or build does not run the requested form");
  const int64_t n = mean.numel() / 3, levels = resolution.size(0);
  GridInputs g{torch::empty({n, 3}, mean.options()), torch::empty({n, levels}, mean.options()),
               torch::empty({n}, mean.options())};
  const auto mc = mean.contiguous(), cc = cov.contiguous(), rc = resolution.contiguous();
  enc::grid_rows(mc.data_ptr<float>(), cc.data_ptr<float>(), n, float(lo), float(hi), rc.data_ptr<float>(), levels,
                 float(scale), form, g.unit.data_ptr<float>(), g.weights.data_ptr<float>(), g.inside.data_ptr<float>());
  return g;
}

}  // namespace ablenerf
