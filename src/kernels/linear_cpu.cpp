#include "kernels/linear_cpu.h"

#include "kernels/small_gemm.h"
#include "kernels/token_product.h"

#include <ATen/record_function.h>
#include <algorithm>
#include <vector>

namespace ablenerf {

namespace {

// The element-wise passes around the products, each body written once and compiled twice: for the
// baseline instructions and for AVX-512 (kernels/cpu_features.h), chosen at run time. They only
// add and select, so every form gives the same bits. Why: compiled for the baseline alone the ReLU's
// gradient was a branch per element that mispredicts on about half of them, and the sums 4 lanes
// wide: together 5% of a training step's samples at the capture preset (perf, 2-core Intel Xeon,
// 2026-12-03).

// out (m, n) += b per row, then max(out, 0) with `relu` (ATen's ReLU: NaN stays NaN, a comparison
// that is false for NaN keeps the value).
ABLENERF_ALWAYS_INLINE void bias_relu_body(float* __restrict out, const float* __restrict b, int64_t m, int64_t n,
                                           bool relu) {
  if (b != nullptr) {
    if (relu) {
      for (int64_t i = 0; i < m; ++i) {
        float* __restrict row = out + i * n;
        for (int64_t j = 0; j < n; ++j) {
          const float v = row[j] + b[j];
          row[j] = v < 0.0f ? 0.0f : v;
        }
      }
    } else {
      for (int64_t i = 0; i < m; ++i) {
        float* __restrict row = out + i * n;
        for (int64_t j = 0; j < n; ++j) row[j] += b[j];
      }
    }
  } else if (relu) {
    for (int64_t i = 0; i < m * n; ++i) out[i] = out[i] < 0.0f ? 0.0f : out[i];
  }
}

// o = g where y > 0, else 0 (ATen's threshold_backward for ReLU).
ABLENERF_ALWAYS_INLINE void relu_gradient_body(const float* __restrict g, const float* __restrict y,
                                               float* __restrict o, int64_t count) {
  for (int64_t i = 0; i < count; ++i) o[i] = y[i] > 0.0f ? g[i] : 0.0f;
}

// out (n) = column sums of dy (m, n). Rows are added into a block's partial sums kRowsPerBlock at a
// time, and the blocks' partials into the total (two levels, so the rounding grows with
// kRowsPerBlock + m / kRowsPerBlock, not m); the inner loop runs along a row. Why not dy.sum(0):
// over the model's narrow token matrices (a 128-ray slice is 2,176 rows of 48-144 features) ATen's
// reduction over the outer dimension took ~80 us per call, 44 calls and 3.65 ms of a ~46 ms
// training step at the capture preset (`ablenerf bench --config configs/capture.toml --set
// data.scene=unbounded --rays 256 --trace T`, 2-core AMD EPYC machine, 2026-11-26).
ABLENERF_ALWAYS_INLINE void column_sums_body(const float* __restrict dy, int64_t m, int64_t n, float* __restrict block,
                                             float* __restrict out) {
  constexpr int64_t kRowsPerBlock = 256;
  for (int64_t lo = 0; lo < m; lo += kRowsPerBlock) {
    for (int64_t j = 0; j < n; ++j) block[j] = 0.0f;
    const int64_t hi = std::min(m, lo + kRowsPerBlock);
    for (int64_t i = lo; i < hi; ++i) {
      const float* __restrict row = dy + i * n;
      for (int64_t j = 0; j < n; ++j) block[j] += row[j];
    }
    for (int64_t j = 0; j < n; ++j) out[j] += block[j];
  }
}

#ifdef ABLENERF_HAVE_AVX2_FORM
ABLENERF_TARGET_AVX512 void bias_relu_avx512(float* out, const float* b, int64_t m, int64_t n, bool relu) {
  bias_relu_body(out, b, m, n, relu);
}
ABLENERF_TARGET_AVX512 void relu_gradient_avx512(const float* g, const float* y, float* o, int64_t count) {
  relu_gradient_body(g, y, o, count);
}
ABLENERF_TARGET_AVX512 void column_sums_avx512(const float* dy, int64_t m, int64_t n, float* block, float* out) {
  column_sums_body(dy, m, n, block, out);
}
#endif

void bias_relu_in(CpuVectorForm form, float* out, const float* b, int64_t m, int64_t n, bool relu) {
#ifdef ABLENERF_HAVE_AVX2_FORM
  if (form == CpuVectorForm::Avx512) return bias_relu_avx512(out, b, m, n, relu);
#endif
  (void)form;
  bias_relu_body(out, b, m, n, relu);
}
void relu_gradient_in(CpuVectorForm form, const float* g, const float* y, float* o, int64_t count) {
#ifdef ABLENERF_HAVE_AVX2_FORM
  if (form == CpuVectorForm::Avx512) return relu_gradient_avx512(g, y, o, count);
#endif
  (void)form;
  relu_gradient_body(g, y, o, count);
}
void column_sums_in(CpuVectorForm form, const float* dy, int64_t m, int64_t n, float* block, float* out) {
#ifdef ABLENERF_HAVE_AVX2_FORM
  if (form == CpuVectorForm::Avx512) return column_sums_avx512(dy, m, n, block, out);
#endif
  (void)form;
  column_sums_body(dy, m, n, block, out);
}

// y (..., N) = x (..., K) W^T (+ b), then max(y, 0) with `relu`, everything contiguous: x's rows as
// one (M, K) matrix; the product in float32 or with bfloat16 operands (kernels/token_product.h).
torch::Tensor forward_product(const torch::Tensor& x, const torch::Tensor& weight, const torch::Tensor& bias, bool relu,
                              CpuVectorForm form, bool bf16) {
  const int64_t k = x.size(-1), m = x.numel() / k, n = weight.size(0);
  // W^T (or W packed) in this thread's scratch: a transpose as a LibTorch op (a view made
  // contiguous) cost ~9 us of dispatch and allocation for a few thousand floats, 25 times a step.
  thread_local WeightOperand w;
  w.prepare(weight.data_ptr<float>(), n, k, WeightOperand::Use::Transposed, bf16);
  auto sizes = x.sizes().vec();
  sizes.back() = n;
  auto y = torch::empty(sizes, x.options());
  w.multiply(m, x.data_ptr<float>(), k, y.data_ptr<float>(), n);
  if (bias.defined() || relu)
    bias_relu_in(form, y.data_ptr<float>(), bias.defined() ? bias.data_ptr<float>() : nullptr, m, n, relu);
  return y;
}

// dy where y > 0, else 0, into a new tensor.
torch::Tensor relu_gradient(const torch::Tensor& dy, const torch::Tensor& y, CpuVectorForm form) {
  auto out = torch::empty_like(y);
  relu_gradient_in(form, dy.data_ptr<float>(), y.data_ptr<float>(), out.data_ptr<float>(), y.numel());
  return out;
}

// Column sums of dy (..., N), contiguous, over all its rows: the bias gradient.
torch::Tensor column_sums(const torch::Tensor& dy, CpuVectorForm form) {
  const int64_t n = dy.size(-1), m = dy.numel() / n;
  auto total = torch::zeros({n}, dy.options());
  std::vector<float> block(static_cast<size_t>(n));
  column_sums_in(form, dy.data_ptr<float>(), m, n, block.data(), total.data_ptr<float>());
  return total;
}

// The largest x (bytes) the weight gradient reads through small_gemm: about a core's L2 cache.
constexpr int64_t kSmallGemmReductionBytes = int64_t{1} << 20;

class LinearFunction : public torch::autograd::Function<LinearFunction> {
 public:
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& x,
                               const torch::Tensor& weight, const torch::Tensor& bias, bool relu, int64_t form) {
    const bool has_bias = bias.numel() > 0;
    // The products' precision is the calling thread's now; the backward may run on another.
    const bool bf16 = token_products_bf16();
    auto y =
        forward_product(x, weight, has_bias ? bias : torch::Tensor(), relu, static_cast<CpuVectorForm>(form), bf16);
    // With the ReLU, its output says where the gradient passes.
    ctx->save_for_backward(relu ? torch::autograd::variable_list{x, weight, y}
                                : torch::autograd::variable_list{x, weight});
    ctx->saved_data["bias"] = has_bias;
    ctx->saved_data["form"] = form;
    ctx->saved_data["bf16"] = bf16;
    return y;
  }

  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                 torch::autograd::variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    const auto &x = saved[0], &weight = saved[1];
    const auto form = static_cast<CpuVectorForm>(ctx->saved_data["form"].toInt());
    const auto dy = saved.size() > 2 ? relu_gradient(grads[0].contiguous(), saved[2], form) : grads[0].contiguous();
    const int64_t k = x.size(-1), m = x.numel() / k, n = weight.size(0);
    const bool bf16 = ctx->saved_data["bf16"].toBool();
    torch::Tensor dx, dw, db;
    if (ctx->needs_input_grad(0)) {
      dx = torch::empty(x.sizes(), x.options());
      thread_local WeightOperand w;
      w.prepare(weight.data_ptr<float>(), n, k, WeightOperand::Use::AsIs, bf16);
      w.multiply(m, dy.data_ptr<float>(), n, dx.data_ptr<float>(), k);
    }
    if (ctx->needs_input_grad(1)) {
      dw = torch::empty({n, k}, x.options());
      // small_gemm reads all of x once for every four rows of dw: from the core's cache at the
      // presets that train on a CPU, from memory at the paper's (50k tokens of width 192 in a
      // slice), where BLAS's blocked product is the one to use. In bfloat16, x packed once.
      if (bf16) {
        thread_local Bf16Operand xp;
        xp.pack(x.data_ptr<float>(), m, k, k, 1);
        bf16_gemm_at(n, dy.data_ptr<float>(), n, xp, dw.data_ptr<float>(), k);
      } else if (m * k * static_cast<int64_t>(sizeof(float)) <= kSmallGemmReductionBytes)
        small_gemm(true, n, k, m, 1.0f, dy.data_ptr<float>(), n, x.data_ptr<float>(), k, dw.data_ptr<float>(), k);
      else
        torch::mm_out(dw, dy.reshape({m, n}).t(), x.reshape({m, k}));
    }
    if (ctx->saved_data["bias"].toBool() && ctx->needs_input_grad(2)) db = column_sums(dy, form);
    return {dx, dw, db, torch::Tensor(), torch::Tensor()};
  }
};

}  // namespace

bool linear_cpu_available(const torch::Tensor& x, const torch::Tensor& weight) {
  return x.device().is_cpu() && weight.device().is_cpu() && x.scalar_type() == torch::kFloat &&
         weight.scalar_type() == torch::kFloat && x.dim() >= 2 && weight.dim() == 2 && x.size(-1) == weight.size(1) &&
         x.numel() > 0 && weight.size(0) > 0;
}

torch::Tensor linear_cpu(const torch::Tensor& x, const torch::Tensor& weight, const torch::Tensor& bias, bool relu,
                         CpuVectorForm form) {
  RECORD_FUNCTION("ablenerf::linear_cpu", std::vector<c10::IValue>());
  TORCH_CHECK(linear_cpu_available(x, weight), "linear_cpu: expected CPU float32 x (..., K) and weight (N, K), got ",
              x.sizes(), " ", x.scalar_type(), " and ", weight.sizes(), " ", weight.scalar_type());
  TORCH_CHECK(!bias.defined() || (bias.dim() == 1 && bias.size(0) == weight.size(0) &&
                                  bias.scalar_type() == torch::kFloat && bias.device().is_cpu()),
              "linear_cpu: bias must be a CPU float32 (", weight.size(0), ") tensor");
  TORCH_CHECK(cpu_vector_form_available(form), "linear_cpu: the AVX-512 form on a CPU without it");
  const auto xc = x.contiguous(), wc = weight.contiguous();
  const auto bc = bias.defined() ? bias.contiguous() : torch::Tensor();
  const bool needs_graph = torch::GradMode::is_enabled() &&
                           (xc.requires_grad() || wc.requires_grad() || (bc.defined() && bc.requires_grad()));
  if (!needs_graph) return forward_product(xc, wc, bc, relu, form, token_products_bf16());
  return LinearFunction::apply(xc, wc, bc.defined() ? bc : torch::empty({0}, x.options()), relu,
                               static_cast<int64_t>(form));
}

}  // namespace ablenerf
