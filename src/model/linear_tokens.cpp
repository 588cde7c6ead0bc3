#include "model/linear_tokens.h"

#include "kernels/linear_cpu.h"

namespace ablenerf {

namespace {

// x (..., in) -> (..., out) as one 2-D product, max(y, 0) after the bias with `relu`.
torch::Tensor tokens_product(const torch::Tensor& x, const torch::Tensor& weight, const torch::Tensor& bias,
                             bool relu) {
  auto sizes = x.sizes().vec();
  const auto flat = x.reshape({-1, sizes.back()});
  torch::Tensor y;
  if (linear_cpu_available(flat, weight)) {
    y = linear_cpu(flat, weight, bias, relu);  // CPU float32: one node (kernels/linear_cpu.h)
  } else {
    y = bias.defined() ? torch::addmm(bias, flat, weight.t()) : flat.mm(weight.t());
    if (relu) y = torch::relu(y);
  }
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
