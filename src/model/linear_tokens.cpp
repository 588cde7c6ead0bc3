#include "model/linear_tokens.h"

#include "kernels/linear_cpu.h"
#include "model/compute.h"

namespace ablenerf {

namespace {

// x W^T + b whose backward gives the bias its gradient as a matrix product, ones(1, rows) dy,
// where addmm's backward sums dy's columns with a reduction kernel. On CUDA in bf16 those sums
// ran at about a fifth of the memory's bandwidth and took a sixth of the GPU's training step
// (docs/BENCHMARKS.md, the GPU profile). x, weight and bias come in the product's dtype already.
class BiasProductFunction : public torch::autograd::Function<BiasProductFunction> {
 public:
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& x,
                               const torch::Tensor& weight, const torch::Tensor& bias) {
    ctx->save_for_backward({x, weight});
    return torch::addmm(bias, x, weight.t());
  }

  static torch::autograd::tensor_list backward(torch::autograd::AutogradContext* ctx,
                                               torch::autograd::tensor_list grads) {
    const auto saved = ctx->get_saved_variables();
    const auto& x = saved[0];
    const auto& weight = saved[1];
    const auto& dy = grads[0];
    torch::Tensor dx, dweight, dbias;
    if (!dy.defined()) return {dx, dweight, dbias};
    if (ctx->needs_input_grad(0)) dx = dy.mm(weight);
    if (ctx->needs_input_grad(1)) dweight = dy.t().mm(x);
    if (ctx->needs_input_grad(2)) dbias = torch::ones({1, dy.size(0)}, dy.options()).mm(dy).view({-1});
    return {dx, dweight, dbias};
  }
};

// addmm(bias, x, weight^T), through BiasProductFunction when the bias needs a gradient.
torch::Tensor bias_product(const torch::Tensor& x, const torch::Tensor& weight, const torch::Tensor& bias) {
  if (!torch::GradMode::is_enabled() || !bias.requires_grad()) return torch::addmm(bias, x, weight.t());
  return BiasProductFunction::apply(autocast_product_operand(x), autocast_product_operand(weight),
                                    autocast_product_operand(bias));
}

// x (..., in) -> (..., out) as one 2-D product, max(y, 0) after the bias with `relu`.
torch::Tensor tokens_product(const torch::Tensor& x, const torch::Tensor& weight, const torch::Tensor& bias,
                             bool relu) {
  // CPU float32: one node that takes the tokens as they are (kernels/linear_cpu.h).
  if (linear_cpu_available(x, weight)) return linear_cpu(x, weight, bias, relu);
  auto sizes = x.sizes().vec();
  const auto flat = x.reshape({-1, sizes.back()});
  auto y = bias.defined() ? bias_product(flat, weight, bias) : flat.mm(weight.t());
  if (relu) y = torch::relu(y);
  sizes.back() = weight.size(0);
  return y.view(sizes);
}

}  // namespace

torch::Tensor linear_tokens(const torch::Tensor& x, const torch::Tensor& weight, const torch::Tensor& bias) {
  return tokens_product(x, weight, bias, /*relu=*/false);
}

torch::Tensor linear_relu_tokens(const torch::nn::Linear& layer, const torch::Tensor& x) {
  return tokens_product(x, layer->weight, layer->bias, /*relu=*/true);
}

torch::Tensor linear_tokens(const torch::nn::Linear& layer, const torch::Tensor& x, bool with_bias) {
  return linear_tokens(x, layer->weight, with_bias && layer->bias.defined() ? layer->bias : torch::Tensor());
}

}  // namespace ablenerf
