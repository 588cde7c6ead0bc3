// The CUDA bias + exact GELU (kernels/bias_gelu.h) against its plain LibTorch reference on the
// GPU: values and the gradients of x and b, in float32 (to ~1e-5) and bfloat16 (to ~1e-2), at the
// model's feed-forward width (576) and at widths that are not multiples of the 64-column blocks,
// over row counts around the block sizes, the run-to-run determinism of db, and the input checks.
#include <gtest/gtest.h>

#include "kernels/bias_gelu.h"
#include "kernels/gpu_test_util.h"

namespace ablenerf {
namespace {

struct Inputs {
  torch::Tensor x, b, dy;
};

// x spread over [-9, 9] or so: both tails of GELU and its derivative's bump around |z| ~ 1.5.
Inputs make_inputs(std::vector<int64_t> shape, torch::ScalarType dtype, uint64_t seed) {
  return {test::cuda_randn(shape, seed, dtype, 3), test::cuda_randn({shape.back()}, seed + 1, torch::kFloat, 0.5),
          test::cuda_randn(shape, seed + 2, dtype)};
}

// y and the gradients [x, b] of sum(y * dy), through the kernel or the reference.
std::vector<torch::Tensor> run(const Inputs& in, bool kernel) {
  auto x = in.x.clone().requires_grad_(), b = in.b.clone().requires_grad_();
  const auto y = kernel ? bias_gelu(x, b) : bias_gelu_reference(x, b);
  y.backward(in.dy);
  return {y.detach(), x.grad(), b.grad()};
}

void compare(std::vector<int64_t> shape, torch::ScalarType dtype, double tol, uint64_t seed) {
  const auto in = make_inputs(shape, dtype, seed);
  const auto got = run(in, true), want = run(in, false);
  const char* names[] = {"y", "dx", "db"};
  for (size_t i = 0; i < got.size(); ++i) {
    EXPECT_EQ(got[i].scalar_type(), want[i].scalar_type()) << names[i];
    EXPECT_LT(test::scaled_error(got[i], want[i]), tol)
        << names[i] << " shape " << torch::IntArrayRef(shape) << " dtype " << dtype;
  }
}

// (rows, cols): one row; rows not a multiple of the 4-row block step; more rows than the
// backward's 256 x 4 thread rows; the model's 576 columns; column counts that leave a partial
// block (100, 1000) or a single column.
const std::vector<std::vector<int64_t>> kShapes = {{1, 576},    {7, 576}, {291, 576},  {4099, 576},
                                                   {2001, 100}, {5, 1},   {1500, 1000}};

TEST(BiasGeluGpu, Float32MatchesReference) {
  ABLENERF_REQUIRE_CUDA();
  uint64_t seed = 100;
  for (const auto& s : kShapes) compare(s, torch::kFloat, 1e-5, seed += 10);
}

TEST(BiasGeluGpu, BFloat16MatchesReference) {
  ABLENERF_REQUIRE_CUDA();
  uint64_t seed = 200;
  for (const auto& s : kShapes) compare(s, torch::kBFloat16, 1e-2, seed += 10);
}

TEST(BiasGeluGpu, TokensOfRaysKeepTheirShape) {
  ABLENERF_REQUIRE_CUDA();
  compare({5, 97, 576}, torch::kFloat, 1e-5, 300);
  compare({5, 97, 576}, torch::kBFloat16, 1e-2, 310);
}

TEST(BiasGeluGpu, BiasGradientIsTheSameOnEveryRun) {
  ABLENERF_REQUIRE_CUDA();
  const auto in = make_inputs({4099, 576}, torch::kFloat, 400);
  const auto first = run(in, true), second = run(in, true);
  for (size_t i = 0; i < first.size(); ++i) EXPECT_TRUE(torch::equal(first[i], second[i])) << i;
}

TEST(BiasGeluGpu, NoRowsGiveAZeroBiasGradient) {
  ABLENERF_REQUIRE_CUDA();
  const auto got = run(make_inputs({0, 576}, torch::kFloat, 500), true);
  EXPECT_EQ(got[0].sizes(), torch::IntArrayRef({0, 576}));
  EXPECT_TRUE(torch::equal(got[2], torch::zeros({576}, got[2].options())));
}

TEST(BiasGeluGpu, BadInputsAreRefusedNamingTheArgument) {
  ABLENERF_REQUIRE_CUDA();
  const auto in = make_inputs({4, 64}, torch::kFloat, 600);
  const auto call = [](const torch::Tensor& x, const torch::Tensor& b) { return [=] { bias_gelu(x, b); }; };
  test::expect_error_naming(call(in.x, in.b.narrow(0, 0, 32)), "b must have shape (64)");
  test::expect_error_naming(call(in.x, in.b.to(torch::kBFloat16)), "b must be Float");
  test::expect_error_naming(call(in.x, in.b.cpu()), "b must be a CUDA tensor");
  test::expect_error_naming(call(in.x.to(torch::kHalf), in.b), "x must be Float or BFloat16");
  const auto square = test::cuda_randn({64, 64}, 1, torch::kFloat);
  test::expect_error_naming(call(square.t(), in.b), "x must be contiguous");
}

}  // namespace
}  // namespace ablenerf
