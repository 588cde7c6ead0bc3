#include "model/linear_tokens.h"

#include "kernels/linear_cpu.h"

namespace ablenerf {

torch::Tensor linear_tokens(const torch::nn::Linear& layer, const torch::Tensor& x, bool with_bias) {
  auto sizes = x.sizes().vec();
  const auto flat = x.reshape({-1, sizes.back()});
  const auto& w = layer->weight;
  const auto bias = with_bias && layer->bias.defined() ? layer->bias : torch::Tensor();
  // CPU float32: one node of register-blocked products (kernels/linear_cpu.h); elsewhere ATen's.
  auto y = linear_cpu_available(flat, w) ? linear_cpu(flat, w, bias)
           : bias.defined()              ? torch::addmm(bias, flat, w.t())
                                         : flat.mm(w.t());
  sizes.back() = w.size(0);
  return y.view(sizes);
}

}  // namespace ablenerf
