// model/linear_tokens.h on CUDA (the bias gradient as a product with a ones row) against ATen's
// addmm and its autograd: in float32 (to ~1e-5) and inside a bf16 autocast scope (to ~1e-2), where
// the result must keep autocast's dtype and the float32 leaves must get float32 gradients.
#include <gtest/gtest.h>

#include "kernels/gpu_test_util.h"
#include "model/compute.h"
#include "model/linear_tokens.h"

namespace ablenerf {
namespace {

struct Case {
  torch::Tensor x, weight, bias, dy;
};

// The in-projection's shape: 192 -> 576 over rays x tokens rows.
Case make_case(int64_t rays, int64_t tokens, int64_t in, int64_t out, uint64_t seed) {
  return {test::cuda_randn({rays, tokens, in}, seed, torch::kFloat),
          test::cuda_randn({out, in}, seed + 1, torch::kFloat, 0.1),
          test::cuda_randn({out}, seed + 2, torch::kFloat, 0.1),
          test::cuda_randn({rays, tokens, out}, seed + 3, torch::kFloat)};
}

std::vector<torch::Tensor> run(const Case& c, bool project, Precision precision) {
  auto x = c.x.clone().requires_grad_(), w = c.weight.clone().requires_grad_(), b = c.bias.clone().requires_grad_();
  torch::Tensor y;
  {
    const AutocastScope autocast(precision, torch::Device(torch::kCUDA));
    y = project ? linear_tokens(x, w, b)
                : torch::addmm(b, x.reshape({-1, x.size(-1)}), w.t()).view({x.size(0), x.size(1), -1});
  }
  y.backward(c.dy.to(y.scalar_type()));
  return {y.detach(), x.grad(), w.grad(), b.grad()};
}

void compare(Precision precision, double tol) {
  const auto c = make_case(64, 97, 192, 576, 21);
  const auto got = run(c, true, precision), want = run(c, false, precision);
  const char* names[] = {"y", "dx", "dweight", "dbias"};
  for (size_t i = 0; i < got.size(); ++i) {
    ASSERT_TRUE(got[i].defined()) << names[i];
    EXPECT_EQ(got[i].scalar_type(), want[i].scalar_type()) << names[i];
    EXPECT_LT(test::scaled_error(got[i], want[i]), tol) << names[i];
  }
  // The bias gradient against dy's column sums in float64.
  const auto sums = c.dy.to(want[0].scalar_type()).to(torch::kDouble).sum(torch::IntArrayRef{0, 1});
  EXPECT_LT(test::scaled_error(got[3], sums), tol);
}

TEST(LinearTokensGpu, Float32MatchesAddmm) {
  ABLENERF_REQUIRE_CUDA();
  compare(Precision::Fp32, 1e-5);
}

TEST(LinearTokensGpu, Bf16AutocastMatchesAddmm) {
  ABLENERF_REQUIRE_CUDA();
  if (!bf16_autocast_available(torch::Device(torch::kCUDA))) GTEST_SKIP() << "bf16 autocast needs LibTorch >= 2";
  const auto c = make_case(4, 8, 16, 24, 3);
  const auto got = run(c, true, Precision::Bf16);
  EXPECT_EQ(got[0].scalar_type(), torch::kBFloat16);
  EXPECT_EQ(got[2].scalar_type(), torch::kFloat);
  compare(Precision::Bf16, 1e-2);
}

}  // namespace
}  // namespace ablenerf
