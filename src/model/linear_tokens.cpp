#include "model/linear_tokens.h"

#include "kernels/linear_cpu.h"

namespace ablenerf {

torch::Tensor linear_tokens(const torch::Tensor& x, const torch::Tensor& weight, const torch::Tensor& bias) {
  auto sizes = x.sizes().vec();
  const auto flat = x.reshape({-1, sizes.back()});
  // CPU float32: one node of register-blocked products (kernels/linear_cpu.h); elsewhere ATen's.
  auto y = linear_cpu_available(flat, weight) ? linear_cpu(flat, weight, bias)
           : bias.defined()                   ? torch::addmm(bias, flat, weight.t())
                                              : flat.mm(weight.t());
  sizes.back() = weight.size(0);
  return y.view(sizes);
}

torch::Tensor linear_relu_tokens(const torch::nn::Linear& layer, const torch::Tensor& x) {
  auto sizes = x.sizes().vec();
  const auto flat = x.reshape({-1, sizes.back()});
  if (!linear_cpu_available(flat, layer->weight)) return torch::relu(linear_tokens(layer, x));
  sizes.back() = layer->weight.size(0);
  return linear_cpu(flat, layer->weight, layer->bias, /*relu=*/true).view(sizes);
}

torch::Tensor linear_tokens(const torch::nn::Linear& layer, const torch::Tensor& x, bool with_bias) {
  return linear_tokens(x, layer->weight, with_bias && layer->bias.defined() ? layer->bias : torch::Tensor());
}

}  // namespace ablenerf
