#include "kernels/linear_cpu.h"

#include "kernels/small_gemm.h"

#include <ATen/record_function.h>
#include <algorithm>
#include <vector>

namespace ablenerf {

namespace {

// y (M, N) = x (M, K) W^T (+ b), then max(y, 0) with `relu`, everything contiguous.
torch::Tensor forward_product(const torch::Tensor& x, const torch::Tensor& weight, const torch::Tensor& bias,
                              bool relu) {
  const int64_t m = x.size(0), k = x.size(1), n = weight.size(0);
  const auto wt = weight.t().contiguous();  // (K, N): B of the product
  auto y = torch::empty({m, n}, x.options());
  small_gemm(false, m, n, k, 1.0f, x.data_ptr<float>(), k, wt.data_ptr<float>(), n, y.data_ptr<float>(), n);
  float* out = y.data_ptr<float>();
  // ReLU as ATen's: NaN stays NaN (a comparison that is false for NaN keeps the value); in the bias's
  // pass when there is a bias.
  const auto cut = [](float v) { return v < 0.0f ? 0.0f : v; };
  if (bias.defined()) {
    const float* b = bias.data_ptr<float>();
    if (relu) {
      for (int64_t i = 0; i < m; ++i)
        for (int64_t j = 0; j < n; ++j) out[i * n + j] = cut(out[i * n + j] + b[j]);
    } else {
      for (int64_t i = 0; i < m; ++i)
        for (int64_t j = 0; j < n; ++j) out[i * n + j] += b[j];
    }
  } else if (relu) {
    for (int64_t i = 0; i < m * n; ++i) out[i] = cut(out[i]);
  }
  return y;
}

// dy where y > 0, else 0 (ATen's threshold_backward for ReLU), into a new tensor.
torch::Tensor relu_gradient(const torch::Tensor& dy, const torch::Tensor& y) {
  auto out = torch::empty_like(y);
  const float *g = dy.data_ptr<float>(), *v = y.data_ptr<float>();
  float* o = out.data_ptr<float>();
  const int64_t count = y.numel();
  for (int64_t i = 0; i < count; ++i) o[i] = v[i] > 0.0f ? g[i] : 0.0f;
  return out;
}

// Column sums of dy (M, N), contiguous: the bias gradient. Rows are added into a block's partial sums
// kRowsPerBlock at a time, and the blocks' partials into the total (two levels, so the rounding
// grows with kRowsPerBlock + M / kRowsPerBlock, not M); the inner loop runs along a row and
// vectorises. Why not dy.sum(0): over the model's narrow token matrices (a 128-ray slice is 2,176
// rows of 48-144 features) ATen's reduction over the outer dimension took ~80 us per call, 44 calls
// and 3.65 ms of a ~46 ms training step at the capture preset (`ablenerf bench --config
// configs/capture.toml --set data.scene=unbounded --rays 256 --trace T`, 2-core AMD EPYC machine,
// 2026-11-26); this loop's own time was not measured apart.
torch::Tensor column_sums(const torch::Tensor& dy) {
  constexpr int64_t kRowsPerBlock = 256;
  const int64_t m = dy.size(0), n = dy.size(1);
  auto total = torch::zeros({n}, dy.options());
  std::vector<float> block(static_cast<size_t>(n));
  const float* y = dy.data_ptr<float>();
  float* out = total.data_ptr<float>();
  for (int64_t lo = 0; lo < m; lo += kRowsPerBlock) {
    std::fill(block.begin(), block.end(), 0.0f);
    float* b = block.data();
    const int64_t hi = std::min(m, lo + kRowsPerBlock);
    for (int64_t i = lo; i < hi; ++i) {
      const float* row = y + i * n;
      for (int64_t j = 0; j < n; ++j) b[j] += row[j];
    }
    for (int64_t j = 0; j < n; ++j) out[j] += b[j];
  }
  return total;
}

class LinearFunction : public torch::autograd::Function<LinearFunction> {
 public:
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& x,
                               const torch::Tensor& weight, const torch::Tensor& bias, bool relu) {
    const bool has_bias = bias.numel() > 0;
    auto y = forward_product(x, weight, has_bias ? bias : torch::Tensor(), relu);
    // With the ReLU, its output says where the gradient passes.
    ctx->save_for_backward(relu ? torch::autograd::variable_list{x, weight, y}
                                : torch::autograd::variable_list{x, weight});
    ctx->saved_data["bias"] = has_bias;
    return y;
  }

  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                 torch::autograd::variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    const auto &x = saved[0], &weight = saved[1];
    const auto dy = saved.size() > 2 ? relu_gradient(grads[0].contiguous(), saved[2]) : grads[0].contiguous();
    const int64_t m = x.size(0), k = x.size(1), n = weight.size(0);
    torch::Tensor dx, dw, db;
    if (ctx->needs_input_grad(0)) {
      dx = torch::empty({m, k}, x.options());
      small_gemm(false, m, k, n, 1.0f, dy.data_ptr<float>(), n, weight.data_ptr<float>(), k, dx.data_ptr<float>(), k);
    }
    if (ctx->needs_input_grad(1)) {
      dw = torch::empty({n, k}, x.options());
      small_gemm(true, n, k, m, 1.0f, dy.data_ptr<float>(), n, x.data_ptr<float>(), k, dw.data_ptr<float>(), k);
    }
    if (ctx->saved_data["bias"].toBool() && ctx->needs_input_grad(2)) db = column_sums(dy);
    return {dx, dw, db, torch::Tensor()};
  }
};

}  // namespace

bool linear_cpu_available(const torch::Tensor& x, const torch::Tensor& weight) {
  return x.device().is_cpu() && weight.device().is_cpu() && x.scalar_type() == torch::kFloat &&
         weight.scalar_type() == torch::kFloat && x.dim() == 2 && weight.dim() == 2 && x.size(1) == weight.size(1) &&
         x.size(0) > 0 && weight.size(0) > 0 && x.size(1) > 0;
}

torch::Tensor linear_cpu(const torch::Tensor& x, const torch::Tensor& weight, const torch::Tensor& bias, bool relu) {
  RECORD_FUNCTION("ablenerf::linear_cpu", std::vector<c10::IValue>());
  TORCH_CHECK(linear_cpu_available(x, weight), "linear_cpu: expected CPU float32 x (M, K) and weight (N, K), got ",
              x.sizes(), " ", x.scalar_type(), " and ", weight.sizes(), " ", weight.scalar_type());
  TORCH_CHECK(!bias.defined() || (bias.dim() == 1 && bias.size(0) == weight.size(0) &&
                                  bias.scalar_type() == torch::kFloat && bias.device().is_cpu()),
              "linear_cpu: bias must be a CPU float32 (", weight.size(0), ") tensor");
  const auto xc = x.contiguous(), wc = weight.contiguous();
  const auto bc = bias.defined() ? bias.contiguous() : torch::Tensor();
  const bool needs_graph = torch::GradMode::is_enabled() &&
                           (xc.requires_grad() || wc.requires_grad() || (bc.defined() && bc.requires_grad()));
  if (!needs_graph) return forward_product(xc, wc, bc, relu);
  return LinearFunction::apply(xc, wc, bc.defined() ? bc : torch::empty({0}, x.options()), relu);
}

}  // namespace ablenerf
