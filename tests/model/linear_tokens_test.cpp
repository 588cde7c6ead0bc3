// model/linear_tokens.h off the CPU float32 kernel (here in float64 on the CPU: the path CUDA
// takes): values and the gradients of x, the weight and the bias against ATen's own addmm and its
// autograd, the bias gradient against the column sums of dy, and the inputs that need no gradient.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include "model/linear_tokens.h"

namespace ablenerf {
namespace {

struct Case {
  torch::Tensor x, weight, bias, dy;
};

Case make_case(int64_t rays, int64_t tokens, int64_t in, int64_t out, uint64_t seed) {
  auto gen = at::detail::createCPUGenerator(seed);
  const auto opts = torch::dtype(torch::kDouble);
  return {torch::randn({rays, tokens, in}, gen, opts), torch::randn({out, in}, gen, opts),
          torch::randn({out}, gen, opts), torch::randn({rays, tokens, out}, gen, opts)};
}

// y and the gradients [x, weight, bias] of sum(y * dy); an entry is undefined where no gradient was asked for.
std::vector<torch::Tensor> run(const Case& c, bool project, bool grad_x, bool grad_weight, bool grad_bias) {
  auto x = c.x.clone().requires_grad_(grad_x), w = c.weight.clone().requires_grad_(grad_weight),
       b = c.bias.clone().requires_grad_(grad_bias);
  const auto y = project ? linear_tokens(x, w, b)
                         : torch::addmm(b, x.reshape({-1, x.size(-1)}), w.t()).view({x.size(0), x.size(1), -1});
  y.backward(c.dy);
  return {y.detach(), x.grad(), w.grad(), b.grad()};
}

TEST(LinearTokens, ValuesAndGradientsEqualAddmmOffTheCpuKernel) {
  // 576 = the feed-forward width, 193 rows per ray: neither a multiple of a block.
  for (const auto& [in, out] : {std::pair<int64_t, int64_t>{192, 576}, {576, 192}, {7, 3}}) {
    const auto c = make_case(5, 193, in, out, 11 + in);
    const auto got = run(c, true, true, true, true), want = run(c, false, true, true, true);
    const char* names[] = {"y", "dx", "dweight", "dbias"};
    for (size_t i = 0; i < got.size(); ++i) {
      ASSERT_TRUE(got[i].defined()) << names[i];
      EXPECT_TRUE(torch::allclose(got[i], want[i], 1e-12, 1e-10)) << names[i] << " " << in << "->" << out;
    }
    // The bias gradient is the column sums of dy.
    EXPECT_TRUE(torch::allclose(got[3], c.dy.sum(torch::IntArrayRef{0, 1}), 1e-12, 1e-10));
  }
}

TEST(LinearTokens, OnlyTheGradientsAskedForAreMade) {
  const auto c = make_case(3, 17, 24, 40, 5);
  const auto want = run(c, false, true, true, true);
  // Bias only (the weight frozen, the input a constant), and everything but the bias.
  const auto bias_only = run(c, true, false, false, true);
  EXPECT_FALSE(bias_only[1].defined());
  EXPECT_FALSE(bias_only[2].defined());
  EXPECT_TRUE(torch::allclose(bias_only[3], want[3], 1e-12, 1e-10));
  const auto no_bias = run(c, true, true, true, false);
  EXPECT_FALSE(no_bias[3].defined());
  EXPECT_TRUE(torch::allclose(no_bias[1], want[1], 1e-12, 1e-10));
  EXPECT_TRUE(torch::allclose(no_bias[2], want[2], 1e-12, 1e-10));
}

TEST(LinearTokens, NoGradientModeGivesTheSameValues) {
  const auto c = make_case(2, 9, 16, 8, 3);
  const auto want = run(c, false, true, true, true)[0];
  torch::NoGradGuard no_grad;
  const auto b = c.bias.clone().requires_grad_();
  EXPECT_TRUE(torch::allclose(linear_tokens(c.x, c.weight, b), want, 1e-12, 1e-10));
}

TEST(LinearTokens, ZeroRowsGiveAZeroBiasGradient) {
  auto x = torch::zeros({0, 4, 6}, torch::kDouble).requires_grad_();
  auto w = torch::randn({5, 6}, torch::kDouble).requires_grad_(),
       b = torch::randn({5}, torch::kDouble).requires_grad_();
  const auto y = linear_tokens(x, w, b);
  EXPECT_EQ(y.sizes(), torch::IntArrayRef({0, 4, 5}));
  y.sum().backward();
  ASSERT_TRUE(b.grad().defined());
  EXPECT_EQ(b.grad().abs().max().item<double>(), 0.0);
}

}  // namespace
}  // namespace ablenerf
