// The residual LayerNorm reference (kernels/residual_layer_norm.h) against LayerNorm written out
// from its definition in float64, its gradients against central finite differences, and the
// CUDA wrapper's refusal of CPU tensors. The kernel itself is compared against this reference in
// residual_layer_norm_gpu_test.cpp.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "kernels/kernel_test_util.h"
#include "kernels/residual_layer_norm.h"

namespace ablenerf {
namespace {

using test::max_abs;
using test::seeded_randn;

constexpr double kEps = 1e-5;

// Row by row from the definition, in double: s = x + r, mean and biased variance of the row,
// y = (s - mean) / sqrt(var + eps) * gamma + beta.
torch::Tensor by_hand(const torch::Tensor& x, const torch::Tensor& r, const torch::Tensor& gamma,
                      const torch::Tensor& beta, double eps) {
  const auto xd = x.to(torch::kDouble).contiguous(), rd = r.to(torch::kDouble).contiguous();
  const auto gd = gamma.to(torch::kDouble).contiguous(), bd = beta.to(torch::kDouble).contiguous();
  const auto xa = xd.accessor<double, 2>(), ra = rd.accessor<double, 2>();
  const auto ga = gd.accessor<double, 1>(), ba = bd.accessor<double, 1>();
  const int64_t n = x.size(0), e = x.size(1);
  auto y = torch::empty({n, e}, torch::kDouble);
  auto ya = y.accessor<double, 2>();
  for (int64_t i = 0; i < n; ++i) {
    double mean = 0, var = 0;
    for (int64_t j = 0; j < e; ++j) mean += xa[i][j] + ra[i][j];
    mean /= double(e);
    for (int64_t j = 0; j < e; ++j) var += (xa[i][j] + ra[i][j] - mean) * (xa[i][j] + ra[i][j] - mean);
    var /= double(e);
    for (int64_t j = 0; j < e; ++j) ya[i][j] = (xa[i][j] + ra[i][j] - mean) / std::sqrt(var + eps) * ga[j] + ba[j];
  }
  return y;
}

TEST(ResidualLayerNormReference, MatchesTheDefinitionInFloat64) {
  const auto x = seeded_randn({6, 12}, 1, 3, 0.5), r = seeded_randn({6, 12}, 2), gamma = seeded_randn({12}, 3, 0.3, 1),
             beta = seeded_randn({12}, 4);
  // Row 2 constant after the residual add: zero variance, so y = beta there (eps keeps it finite).
  x[2].fill_(2.5);
  r[2].fill_(-1);
  const auto want = by_hand(x, r, gamma, beta, kEps);
  const auto got = residual_layer_norm_reference(x, r, gamma, beta, kEps);
  EXPECT_EQ(got.scalar_type(), torch::kDouble);
  EXPECT_LT(max_abs(got - want), 1e-12);
  EXPECT_LT(max_abs(got[2] - beta), 1e-12);
  // eps is used: a large one changes the result as the definition says.
  EXPECT_LT(max_abs(residual_layer_norm_reference(x, r, gamma, beta, 0.5) - by_hand(x, r, gamma, beta, 0.5)), 1e-12);
}

TEST(ResidualLayerNormReference, LowerPrecisionInputsAreComputedInFloatAndReturnedInTheirDtype) {
  const auto x = seeded_randn({7, 64}, 5, 2), r = seeded_randn({7, 64}, 6), gamma = seeded_randn({64}, 7, 0.3, 1),
             beta = seeded_randn({64}, 8);
  const auto g = gamma.to(torch::kFloat), b = beta.to(torch::kFloat);
  const auto xf = x.to(torch::kFloat), rf = r.to(torch::kFloat);
  const auto yf = residual_layer_norm_reference(xf, rf, g, b, kEps);
  EXPECT_EQ(yf.scalar_type(), torch::kFloat);
  EXPECT_LT(max_abs(yf.to(torch::kDouble) - by_hand(xf, rf, g, b, kEps)), 1e-5);
  // bfloat16 in, bfloat16 out: the exact result of the bfloat16 inputs, rounded once.
  const auto xb = x.to(torch::kBFloat16), rb = r.to(torch::kBFloat16);
  const auto yb = residual_layer_norm_reference(xb, rb, g, b, kEps);
  EXPECT_EQ(yb.scalar_type(), torch::kBFloat16);
  const auto want = by_hand(xb, rb, g, b, kEps);
  EXPECT_LT(max_abs(yb.to(torch::kDouble) - want), 1e-2 * max_abs(want));
  EXPECT_LT(max_abs(yb.to(torch::kDouble) - want.to(torch::kBFloat16).to(torch::kDouble)), 1e-2 * max_abs(want));
}

TEST(ResidualLayerNormReference, GradientsMatchFiniteDifferences) {
  const std::vector<torch::Tensor> inputs = {seeded_randn({3, 8}, 9, 2), seeded_randn({3, 8}, 10),
                                             seeded_randn({8}, 11, 0.3, 1), seeded_randn({8}, 12)};
  const auto weights = seeded_randn({3, 8}, 13);  // a loss that weighs every output differently
  const test::ScalarFunction loss = [&](const std::vector<torch::Tensor>& in) {
    return (residual_layer_norm_reference(in[0], in[1], in[2], in[3], kEps) * weights).sum();
  };
  const auto grads = test::autograd_gradients(loss, inputs);
  for (size_t i = 0; i < inputs.size(); ++i) {
    const auto numeric = test::numeric_gradient(loss, inputs, i);
    EXPECT_LT(max_abs(grads[i] - numeric), 1e-7) << "input " << i;
    EXPECT_GT(max_abs(grads[i]), 1e-3) << "input " << i;  // a real gradient, not zeros on both sides
  }
  // x and r enter only through their sum: one gradient for both.
  EXPECT_LT(max_abs(grads[0] - grads[1]), 1e-15);
}

TEST(ResidualLayerNorm, WrapperRefusesCpuTensors) {
  const auto x = torch::zeros({2, 32}), gamma = torch::ones({32}), beta = torch::zeros({32});
  try {
    residual_layer_norm(x, x, gamma, beta, kEps);
    FAIL() << "no error for CPU tensors";
  } catch (const c10::Error& e) {
    const std::string msg = e.what();
#ifdef ABLENERF_CUDA_KERNELS
    EXPECT_NE(msg.find("residual_layer_norm: x must be a CUDA tensor"), std::string::npos) << msg;
#else
    EXPECT_NE(msg.find("residual_layer_norm: built without CUDA kernels"), std::string::npos) << msg;
#endif
  }
}

}  // namespace
}  // namespace ablenerf
