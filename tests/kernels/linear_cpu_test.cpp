// The CPU token linear layer (kernels/linear_cpu.h) against LibTorch's torch::linear, the plain
// reference: the same values and the same gradients for x, W and b, with and without a bias,
// with widths that fill whole SIMD vectors and widths that leave columns over (including a
// reduction longer than 64 with such columns), an x too large for the small products' weight
// gradient, and with only some inputs requiring gradients.
#include <gtest/gtest.h>

#include "kernels/kernel_test_util.h"
#include "kernels/linear_cpu.h"

namespace ablenerf {
namespace {

struct LinearCase {
  int64_t m, k, n;
  bool bias;
  bool relu = false;
};

// Output and gradients {y, dx, dW (, db)} of `layer` (linear_cpu or a reference) for the case's
// seeded float32 inputs and one upstream gradient.
template <class Layer>
std::vector<torch::Tensor> linear_outputs(const LinearCase& c, uint64_t seed, Layer&& layer) {
  auto x = test::seeded_randn({c.m, c.k}, seed).to(torch::kFloat).requires_grad_();
  auto w = test::seeded_randn({c.n, c.k}, seed + 1).to(torch::kFloat).requires_grad_();
  auto b = test::seeded_randn({c.n}, seed + 2).to(torch::kFloat).requires_grad_();
  const auto up = test::seeded_randn({c.m, c.n}, seed + 3).to(torch::kFloat);
  const auto y = layer(x, w, c.bias ? b : torch::Tensor());
  (y * up).sum().backward();
  std::vector<torch::Tensor> out{y.detach(), x.grad(), w.grad()};
  if (c.bias) out.push_back(b.grad());
  return out;
}

std::vector<torch::Tensor> linear_cpu_outputs(const LinearCase& c, uint64_t seed, CpuVectorForm form) {
  return linear_outputs(c, seed, [&](const torch::Tensor& x, const torch::Tensor& w, const torch::Tensor& b) {
    return linear_cpu(x, w, b, c.relu, form);
  });
}

// Values and gradients of linear_cpu and torch::linear for one upstream gradient; float32 inputs,
// errors relative to the size of the sums (k or m terms of unit scale).
void compare_linear(const LinearCase& c, uint64_t seed, CpuVectorForm form = cpu_best_vector_form()) {
  const auto got = linear_cpu_outputs(c, seed, form);
  const auto want =
      linear_outputs(c, seed, [&](const torch::Tensor& x, const torch::Tensor& w, const torch::Tensor& b) {
        return c.relu ? torch::relu(torch::linear(x, w, b)) : torch::linear(x, w, b);
      });
  const double scale[] = {double(c.k), double(c.n), double(c.m), double(c.m)};  // terms per sum
  for (size_t i = 0; i < got.size(); ++i) {
    ASSERT_EQ(got[i].sizes(), want[i].sizes()) << i;
    EXPECT_LT((got[i] - want[i]).abs().max().item<double>(), 2e-6 * scale[i] + 1e-5)
        << "output/gradient " << i << " m " << c.m << " k " << c.k << " n " << c.n;
  }
}

TEST(LinearCpu, MatchesTorchLinear) {
  uint64_t seed = 1;
  for (const LinearCase& c : std::vector<LinearCase>{{2176, 48, 144, true},  // the demo preset's QKV projection
                                                     {2176, 32, 96, true},   // the capture preset's
                                                     {2176, 64, 32, true},
                                                     {300, 48, 48, false},
                                                     {37, 60, 48, true},   // an embedding layer's odd input width
                                                     {50, 100, 13, true},  // columns over, reduction > 64
                                                     {5, 7, 3, true},
                                                     // x over 1 MiB: the weight gradient through BLAS
                                                     // (the paper's model: 50k tokens of width 192)
                                                     {3104, 192, 100, true}})
    compare_linear(c, seed += 4);
}

// With the ReLU in the node (the MLPs' hidden layers): against torch::relu of torch::linear, values
// and gradients, about half the outputs cut; and the cut ones pass no gradient back.
TEST(LinearCpu, WithReluMatchesTorchReluOfLinear) {
  uint64_t seed = 40;
  for (const LinearCase& c : std::vector<LinearCase>{{2176, 44, 32, true, true},  // the volume embedding's first
                                                     {512, 20, 64, true, true},   // the proposal field's hidden
                                                     {17, 5, 3, false, true}})
    compare_linear(c, seed += 4);
  // One output row cut entirely: x's gradient there is zero, the weight's gets nothing from it.
  auto x = torch::tensor({{1.f, 2.f}, {-1.f, -2.f}}).requires_grad_();
  auto w = torch::tensor({{1.f, 1.f}, {2.f, 0.5f}}).requires_grad_();
  const auto y = linear_cpu(x, w, torch::Tensor(), /*relu=*/true);
  EXPECT_TRUE(torch::equal(y.detach(), torch::tensor({{3.f, 3.f}, {0.f, 0.f}})));
  y.sum().backward();
  EXPECT_TRUE(torch::equal(x.grad(), torch::tensor({{3.f, 1.5f}, {0.f, 0.f}})));
  EXPECT_TRUE(torch::equal(w.grad(), torch::tensor({{1.f, 2.f}, {1.f, 2.f}})));
}

// The scalar form of the element-wise passes (bias, ReLU, its gradient, the bias's gradient) against
// torch::linear as well, and against the form this CPU picks bit for bit: they only add and select.
TEST(LinearCpu, ScalarFormMatchesTorchAndTheVectorFormToTheBit) {
  uint64_t seed = 70;
  const std::vector<LinearCase> cases{{2176, 32, 96, true},        // the capture preset's QKV projection
                                      {2176, 44, 32, true, true},  // with the ReLU
                                      {50, 100, 13, true, true},   // columns over the vector length
                                      {17, 5, 3, false, true},     // ReLU without a bias
                                      {1, 3, 1, true}};            // one row, one column
  for (const LinearCase& c : cases) {
    compare_linear(c, seed += 4, CpuVectorForm::Scalar);
    const auto scalar = linear_cpu_outputs(c, seed, CpuVectorForm::Scalar);
    const auto best = linear_cpu_outputs(c, seed, cpu_best_vector_form());
    for (size_t i = 0; i < scalar.size(); ++i)
      EXPECT_TRUE(torch::equal(scalar[i], best[i])) << "output/gradient " << i << " m " << c.m << " n " << c.n;
  }
  if (!cpu_vector_form_available(CpuVectorForm::Avx512)) {
    EXPECT_THROW(linear_cpu(torch::ones({2, 2}), torch::ones({2, 2}), torch::Tensor(), false, CpuVectorForm::Avx512),
                 c10::Error);
  }
}

TEST(LinearCpu, GradientsOnlyWhereRequired) {
  const auto x = test::seeded_randn({20, 16}, 5).to(torch::kFloat);
  auto w = test::seeded_randn({8, 16}, 6).to(torch::kFloat).requires_grad_();
  const auto y = linear_cpu(x, w, torch::Tensor());
  y.sum().backward();
  ASSERT_TRUE(w.grad().defined());
  EXPECT_LT((w.grad() - x.sum(0).expand({8, 16})).abs().max().item<double>(), 1e-4);  // d/dW of sum(x W^T)
  EXPECT_FALSE(x.requires_grad());
  // Without gradients anywhere no graph is recorded.
  torch::NoGradGuard no_grad;
  EXPECT_FALSE(linear_cpu(x, w, torch::Tensor()).requires_grad());
}

// Tokens (rays, tokens, K) go in as they are and come out (rays, tokens, N), values and gradients
// those of torch::linear, also from a non-contiguous input (a transposed view) and with the ReLU.
TEST(LinearCpu, TakesTokensAsTheyAre) {
  for (const bool relu : {false, true}) {
    auto x = test::seeded_randn({6, 17, 12}, 90).to(torch::kFloat).requires_grad_();
    auto xt = test::seeded_randn({6, 12, 17}, 91).to(torch::kFloat).requires_grad_();
    auto w = test::seeded_randn({10, 12}, 92).to(torch::kFloat).requires_grad_();
    auto b = test::seeded_randn({10}, 93).to(torch::kFloat).requires_grad_();
    const auto up = test::seeded_randn({6, 17, 10}, 94).to(torch::kFloat);
    for (auto* in : {&x, &xt}) {
      const auto tokens = in == &x ? x : xt.transpose(1, 2);  // the second not contiguous
      const auto ref = [&](const torch::Tensor& t) {
        auto y = torch::linear(t, w, b);
        return relu ? torch::relu(y) : y;
      };
      const auto got = linear_cpu(tokens, w, b, relu);
      ASSERT_EQ(got.sizes(), (std::vector<int64_t>{6, 17, 10}));
      const auto grads = torch::autograd::grad({(got * up).sum()}, {*in, w, b});
      const auto want = ref(tokens);
      const auto want_grads = torch::autograd::grad({(want * up).sum()}, {*in, w, b});
      EXPECT_LT((got - want).abs().max().item<double>(), 1e-5);
      for (size_t i = 0; i < grads.size(); ++i) {
        ASSERT_EQ(grads[i].sizes(), want_grads[i].sizes()) << i;
        EXPECT_LT((grads[i] - want_grads[i]).abs().max().item<double>(), 1e-4) << "gradient " << i;
      }
    }
  }
}

TEST(LinearCpu, AvailableOnlyForCpuFloat32MatricesOrTokens) {
  EXPECT_TRUE(linear_cpu_available(torch::zeros({3, 4}), torch::zeros({5, 4})));
  EXPECT_TRUE(linear_cpu_available(torch::zeros({2, 3, 4}), torch::zeros({5, 4})));
  EXPECT_FALSE(linear_cpu_available(torch::zeros({3, 4}, torch::kDouble), torch::zeros({5, 4}, torch::kDouble)));
  EXPECT_FALSE(linear_cpu_available(torch::zeros({3, 4}), torch::zeros({5, 3})));
  EXPECT_FALSE(linear_cpu_available(torch::zeros({4}), torch::zeros({5, 4})));
  EXPECT_FALSE(linear_cpu_available(torch::zeros({0, 4}), torch::zeros({5, 4})));
}

}  // namespace
}  // namespace ablenerf
