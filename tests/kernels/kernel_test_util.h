#pragma once
// Shared by the kernels' CPU tests: seeded float64 inputs (the same numbers on every machine), the
// largest magnitude of a tensor, and central finite differences (the gradient of a scalar function
// of several float64 tensors with respect to one of them, element by element, without autograd).
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <functional>
#include <string>
#include <vector>

namespace ablenerf::test {

// Normal numbers * scale + offset in float64 from a generator seeded with `seed`.
inline torch::Tensor seeded_randn(std::vector<int64_t> sizes, uint64_t seed, double scale = 1, double offset = 0) {
  auto gen = at::detail::createCPUGenerator(seed);
  return torch::randn(sizes, gen, torch::kDouble) * scale + offset;
}

// max |t| as a double.
inline double max_abs(const torch::Tensor& t) { return t.abs().max().item<double>(); }

using ScalarFunction = std::function<torch::Tensor(const std::vector<torch::Tensor>&)>;

// d f(inputs) / d inputs[which], by (f(v + h) - f(v - h)) / 2h for every element v. Error O(h^2).
inline torch::Tensor numeric_gradient(const ScalarFunction& f, std::vector<torch::Tensor> inputs, size_t which,
                                      double h = 1e-6) {
  torch::NoGradGuard no_grad;
  for (auto& t : inputs) t = t.detach().clone();
  auto flat = inputs[which].view(-1);
  auto grad = torch::zeros_like(flat);
  for (int64_t i = 0; i < flat.numel(); ++i) {
    const double v = flat[i].item<double>();
    flat[i] = v + h;
    const double up = f(inputs).item<double>();
    flat[i] = v - h;
    const double down = f(inputs).item<double>();
    flat[i] = v;
    grad[i] = (up - down) / (2 * h);
  }
  return grad.view_as(inputs[which]);
}

// The autograd gradients of f at inputs, one per input (each input a fresh leaf).
inline std::vector<torch::Tensor> autograd_gradients(const ScalarFunction& f,
                                                     const std::vector<torch::Tensor>& inputs) {
  std::vector<torch::Tensor> leaves;
  for (const auto& t : inputs) leaves.push_back(t.detach().clone().requires_grad_());
  return torch::autograd::grad({f(leaves)}, leaves);
}

// Runs fn, expects a c10::Error whose message contains `needle` (the argument it names).
template <class Fn>
void expect_error_naming(const Fn& fn, const std::string& needle) {
  try {
    fn();
    ADD_FAILURE() << "no error; expected one naming \"" << needle << "\"";
  } catch (const c10::Error& e) {
    EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
  }
}

}  // namespace ablenerf::test
