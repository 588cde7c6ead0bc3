// The bias + GELU reference (kernels/bias_gelu.h) against the exact GELU written with std::erf,
// its gradients against the closed form Phi(z) + z phi(z) and against central finite
// differences, and the CUDA wrapper's refusal of CPU tensors. The kernel itself is compared
// against this reference in bias_gelu_gpu_test.cpp.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "kernels/bias_gelu.h"
#include "kernels/kernel_test_util.h"

namespace ablenerf {
namespace {

using test::max_abs;
using test::seeded_randn;

// f(x[i][j] + b[j]) for every element, in double.
template <class F>
torch::Tensor elementwise(const torch::Tensor& x, const torch::Tensor& b, const F& f) {
  const auto xd = x.to(torch::kDouble).contiguous(), bd = b.to(torch::kDouble).contiguous();
  const auto xa = xd.accessor<double, 2>();
  const auto ba = bd.accessor<double, 1>();
  auto y = torch::empty(xd.sizes(), torch::kDouble);
  auto ya = y.accessor<double, 2>();
  for (int64_t i = 0; i < xd.size(0); ++i)
    for (int64_t j = 0; j < xd.size(1); ++j) ya[i][j] = f(xa[i][j] + ba[j]);
  return y;
}

double gelu(double z) { return 0.5 * z * (1 + std::erf(z / std::sqrt(2.0))); }
double gelu_grad(double z) {
  const double pi = std::acos(-1.0);
  return 0.5 * (1 + std::erf(z / std::sqrt(2.0))) + z * std::exp(-0.5 * z * z) / std::sqrt(2 * pi);
}

TEST(BiasGeluReference, MatchesTheErfFormulaInFloat64) {
  const auto x = seeded_randn({6, 10}, 1, 3), b = seeded_randn({10}, 2);
  const auto got = bias_gelu_reference(x, b);
  EXPECT_EQ(got.scalar_type(), torch::kDouble);
  const auto want = elementwise(x, b, gelu);
  EXPECT_LT(max_abs(got - want), 1e-14);
  // Not the tanh approximation: the two differ by ~1e-4 around |z| = 2.
  const auto z = torch::full({1, 1}, 2.0, torch::kDouble);
  const auto tanh_form = 0.5 * z * (1 + torch::tanh(std::sqrt(2 / std::acos(-1.0)) * (z + 0.044715 * z * z * z)));
  EXPECT_LT(std::abs(bias_gelu_reference(z, torch::zeros({1}, torch::kDouble)).item<double>() - gelu(2.0)), 1e-15);
  EXPECT_GT(std::abs(tanh_form.item<double>() - gelu(2.0)), 1e-5);
}

TEST(BiasGeluReference, LowerPrecisionInputsAreComputedInFloatAndReturnedInTheirDtype) {
  const auto x = seeded_randn({5, 40}, 3, 3), b = seeded_randn({40}, 4).to(torch::kFloat);
  const auto xf = x.to(torch::kFloat);
  const auto yf = bias_gelu_reference(xf, b);
  EXPECT_EQ(yf.scalar_type(), torch::kFloat);
  EXPECT_LT(max_abs(yf.to(torch::kDouble) - elementwise(xf, b, gelu)), 1e-5);
  const auto xb = x.to(torch::kBFloat16);
  const auto yb = bias_gelu_reference(xb, b);
  EXPECT_EQ(yb.scalar_type(), torch::kBFloat16);
  const auto want = elementwise(xb, b, gelu);  // exact for the bfloat16 inputs, then rounded once
  EXPECT_LT(max_abs(yb.to(torch::kDouble) - want), 1e-2 * max_abs(want));
}

TEST(BiasGeluReference, GradientIsThePhiPlusZPhiClosedForm) {
  const auto x = seeded_randn({9, 7}, 5, 3), b = seeded_randn({7}, 6), dy = seeded_randn({9, 7}, 7);
  const auto grads = test::autograd_gradients(
      [&](const std::vector<torch::Tensor>& in) { return (bias_gelu_reference(in[0], in[1]) * dy).sum(); }, {x, b});
  const auto dx = dy * elementwise(x, b, gelu_grad);
  EXPECT_LT(max_abs(grads[0] - dx), 1e-13);
  EXPECT_LT(max_abs(grads[1] - dx.sum(0)), 1e-12);  // db: column sums of dx
}

TEST(BiasGeluReference, GradientsMatchFiniteDifferences) {
  const std::vector<torch::Tensor> inputs = {seeded_randn({4, 6}, 8, 2), seeded_randn({6}, 9)};
  const auto weights = seeded_randn({4, 6}, 10);
  const test::ScalarFunction loss = [&](const std::vector<torch::Tensor>& in) {
    return (bias_gelu_reference(in[0], in[1]) * weights).sum();
  };
  const auto grads = test::autograd_gradients(loss, inputs);
  for (size_t i = 0; i < inputs.size(); ++i) {
    EXPECT_LT(max_abs(grads[i] - test::numeric_gradient(loss, inputs, i)), 1e-7) << "input " << i;
    EXPECT_GT(max_abs(grads[i]), 1e-3) << "input " << i;
  }
}

TEST(BiasGelu, WrapperRefusesCpuTensors) {
  try {
    bias_gelu(torch::zeros({2, 8}), torch::zeros({8}));
    FAIL() << "no error for CPU tensors";
  } catch (const c10::Error& e) {
    const std::string msg = e.what();
#ifdef ABLENERF_CUDA_KERNELS
    EXPECT_NE(msg.find("bias_gelu: x must be a CUDA tensor"), std::string::npos) << msg;
#else
    EXPECT_NE(msg.find("bias_gelu: built without CUDA kernels"), std::string::npos) << msg;
#endif
  }
}

}  // namespace
}  // namespace ablenerf
