// The CUDA residual add + LayerNorm (kernels/residual_layer_norm.h) against its plain LibTorch
// reference on the GPU: values and the gradients of x, r, gamma and beta, in float32 (to ~1e-5)
// and bfloat16 (to ~1e-2), over widths from one value per lane to 32, row counts around the
// kernels' block sizes, the zero-variance row, the run-to-run determinism of the parameter
// gradients, and the input checks.
#include <gtest/gtest.h>

#include "kernels/gpu_test_util.h"
#include "kernels/residual_layer_norm.h"

namespace ablenerf {
namespace {

constexpr double kEps = 1e-5;

struct Inputs {
  torch::Tensor x, r, gamma, beta, dy;
};

Inputs make_inputs(std::vector<int64_t> shape, torch::ScalarType dtype, uint64_t seed) {
  const int64_t e = shape.back();
  return {test::cuda_randn(shape, seed, dtype, 2, 0.5), test::cuda_randn(shape, seed + 1, dtype),
          test::cuda_randn({e}, seed + 2, torch::kFloat, 0.3, 1), test::cuda_randn({e}, seed + 3, torch::kFloat, 0.2),
          test::cuda_randn(shape, seed + 4, dtype)};
}

// y and the gradients [x, r, gamma, beta] of sum(y * dy), through the kernel or the reference.
std::vector<torch::Tensor> run(const Inputs& in, bool kernel) {
  auto x = in.x.clone().requires_grad_(), r = in.r.clone().requires_grad_();
  auto gamma = in.gamma.clone().requires_grad_(), beta = in.beta.clone().requires_grad_();
  const auto y =
      kernel ? residual_layer_norm(x, r, gamma, beta, kEps) : residual_layer_norm_reference(x, r, gamma, beta, kEps);
  y.backward(in.dy);
  return {y.detach(), x.grad(), r.grad(), gamma.grad(), beta.grad()};
}

void compare(std::vector<int64_t> shape, torch::ScalarType dtype, double tol, uint64_t seed) {
  const auto in = make_inputs(shape, dtype, seed);
  const auto got = run(in, true), want = run(in, false);
  const char* names[] = {"y", "dx", "dr", "dgamma", "dbeta"};
  for (size_t i = 0; i < got.size(); ++i) {
    EXPECT_EQ(got[i].scalar_type(), want[i].scalar_type()) << names[i];
    EXPECT_LT(test::scaled_error(got[i], want[i]), tol)
        << names[i] << " shape " << torch::IntArrayRef(shape) << " dtype " << dtype;
  }
  EXPECT_TRUE(torch::equal(got[1], got[2]));  // x and r receive the same gradient
}

// (rows, width): one row; rows that are not a multiple of the 8 rows per block; more rows than
// the backward's 1024 blocks x 8 rows cover in one pass; widths of 1, 3, 6 (the model's 192), 15
// and 32 values per lane.
const std::vector<std::vector<int64_t>> kShapes = {{1, 192},   {7, 32},     {97, 192}, {291, 96},
                                                   {4099, 64}, {9001, 192}, {33, 480}, {21, 1024}};

TEST(ResidualLayerNormGpu, Float32MatchesReference) {
  ABLENERF_REQUIRE_CUDA();
  uint64_t seed = 100;
  for (const auto& s : kShapes) compare(s, torch::kFloat, 1e-5, seed += 10);
}

TEST(ResidualLayerNormGpu, BFloat16MatchesReference) {
  ABLENERF_REQUIRE_CUDA();
  uint64_t seed = 200;
  for (const auto& s : kShapes) compare(s, torch::kBFloat16, 1e-2, seed += 10);
}

TEST(ResidualLayerNormGpu, TokensOfRaysKeepTheirShape) {
  ABLENERF_REQUIRE_CUDA();
  compare({5, 97, 192}, torch::kFloat, 1e-5, 300);  // (rays, tokens, width), as the model holds them
  compare({5, 97, 192}, torch::kBFloat16, 1e-2, 310);
}

TEST(ResidualLayerNormGpu, ConstantRowGivesBeta) {
  ABLENERF_REQUIRE_CUDA();
  auto in = make_inputs({3, 192}, torch::kFloat, 400);
  in.x[1].fill_(2.5);
  in.r[1].fill_(-1.0);
  const auto got = run(in, true), want = run(in, false);
  EXPECT_LT(test::scaled_error(got[0][1], in.beta), 1e-6);
  for (size_t i = 0; i < got.size(); ++i) EXPECT_LT(test::scaled_error(got[i], want[i]), 1e-5) << i;
}

TEST(ResidualLayerNormGpu, ParameterGradientsAreTheSameOnEveryRun) {
  ABLENERF_REQUIRE_CUDA();
  const auto in = make_inputs({9001, 192}, torch::kFloat, 500);
  const auto first = run(in, true), second = run(in, true);
  for (size_t i = 0; i < first.size(); ++i) EXPECT_TRUE(torch::equal(first[i], second[i])) << i;
}

TEST(ResidualLayerNormGpu, NoRowsGiveZeroParameterGradients) {
  ABLENERF_REQUIRE_CUDA();
  const auto in = make_inputs({0, 64}, torch::kFloat, 600);
  const auto got = run(in, true);
  EXPECT_EQ(got[0].sizes(), torch::IntArrayRef({0, 64}));
  EXPECT_TRUE(torch::equal(got[3], torch::zeros_like(in.gamma)));
  EXPECT_TRUE(torch::equal(got[4], torch::zeros_like(in.beta)));
}

TEST(ResidualLayerNormGpu, BadInputsAreRefusedNamingTheArgument) {
  ABLENERF_REQUIRE_CUDA();
  const auto in = make_inputs({4, 64}, torch::kFloat, 700);
  const auto call = [&](const torch::Tensor& x, const torch::Tensor& r, const torch::Tensor& gamma,
                        const torch::Tensor& beta) { return [=] { residual_layer_norm(x, r, gamma, beta, kEps); }; };
  const auto odd = test::cuda_randn({4, 100}, 1, torch::kFloat);
  test::expect_error_naming(call(odd, odd, torch::ones({100}, odd.options()), torch::zeros({100}, odd.options())),
                            "last dimension (100)");
  const auto wide = test::cuda_randn({2, 2048}, 2, torch::kFloat);
  test::expect_error_naming(call(wide, wide, torch::ones({2048}, wide.options()), torch::zeros({2048}, wide.options())),
                            "last dimension (2048)");
  test::expect_error_naming(call(in.x, in.r.to(torch::kBFloat16), in.gamma, in.beta), "r must be");
  test::expect_error_naming(call(in.x, in.r.narrow(0, 0, 2), in.gamma, in.beta), "r must have x's shape");
  test::expect_error_naming(call(in.x, in.r, in.gamma.to(torch::kBFloat16), in.beta), "gamma must be Float");
  test::expect_error_naming(call(in.x, in.r, in.gamma, in.beta.narrow(0, 0, 32)), "beta must have shape (64)");
  test::expect_error_naming(call(in.x, in.r, in.gamma.cpu(), in.beta), "gamma must be a CUDA tensor");
  test::expect_error_naming(call(in.x.to(torch::kDouble), in.r.to(torch::kDouble), in.gamma, in.beta),
                            "x must be Float or BFloat16");
  const auto square = test::cuda_randn({64, 64}, 3, torch::kFloat);
  test::expect_error_naming(call(square.t(), square, in.gamma, in.beta), "x must be contiguous");
}

}  // namespace
}  // namespace ablenerf
