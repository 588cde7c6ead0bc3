// The token products' two precisions (kernels/token_product.h): WeightOperand against LibTorch for
// both uses in float32 and bfloat16; linear_cpu inside a TokenProductsBf16Scope against the rounded
// operands' products in float64 (y = bf16(x) bf16(W)^T + b, dx = bf16(dy) bf16(W), dW = bf16(dy)^T
// bf16(x), db from the float32 values), its backward keeping the forward's precision after the scope has closed;
// block_tail in bfloat16 near the float32 reference in values and gradients and not equal to its
// own float32 result; the scope refused on a CPU without bfloat16 tiles.
#include <gtest/gtest.h>

#include "kernels/block_tail.h"
#include "kernels/kernel_test_util.h"
#include "kernels/linear_cpu.h"
#include "kernels/token_product.h"

namespace ablenerf {
namespace token_product_test {

torch::Tensor rounded(const torch::Tensor& t) { return t.to(torch::kBFloat16).to(torch::kDouble); }

TEST(TokenProduct, WeightOperandMatchesLibTorchInBothUsesAndPrecisions) {
  const int64_t n = 40, k = 24, m = 37;
  const auto w = test::seeded_randn({n, k}, 1).to(torch::kFloat);
  for (const bool bf16 : {false, true}) {
    if (bf16 && !cpu_has_bf16_products()) continue;
    for (const auto use : {WeightOperand::Use::Transposed, WeightOperand::Use::AsIs}) {
      const bool t = use == WeightOperand::Use::Transposed;
      const int64_t inner = t ? k : n, outer = t ? n : k;
      const auto a = test::seeded_randn({m, inner}, 2).to(torch::kFloat);
      WeightOperand op;
      op.prepare(w.data_ptr<float>(), n, k, use, bf16);
      EXPECT_EQ(op.inner(), inner);
      EXPECT_EQ(op.outer(), outer);
      auto c = torch::empty({m, outer});
      op.multiply(m, a.data_ptr<float>(), inner, c.data_ptr<float>(), outer);
      const auto wd = bf16 ? rounded(w) : w.to(torch::kDouble);
      const auto ad = bf16 ? rounded(a) : a.to(torch::kDouble);
      const auto want = ad.matmul(t ? wd.t() : wd);
      EXPECT_LT(test::max_abs(c.to(torch::kDouble) - want), 1e-4) << "bf16 " << bf16 << " transposed " << t;
    }
  }
}

TEST(TokenProduct, LinearCpuInBf16MatchesTheRoundedProducts) {
  if (!cpu_has_bf16_products()) GTEST_SKIP() << "no AMX bfloat16 tiles on this CPU";
  for (const bool relu : {false, true}) {
    const int64_t m = 70, k = 48, n = 33;
    auto x = test::seeded_randn({2, m / 2, k}, 5).to(torch::kFloat).requires_grad_();
    auto w = test::seeded_randn({n, k}, 6, 0.2).to(torch::kFloat).requires_grad_();
    auto b = test::seeded_randn({n}, 7).to(torch::kFloat).requires_grad_();
    const auto up = test::seeded_randn({2, m / 2, n}, 8).to(torch::kFloat);
    torch::Tensor y;
    {
      const TokenProductsBf16Scope scope(true);
      y = linear_cpu(x, w, b, relu);
    }
    // The backward runs outside the scope and must keep the forward's precision.
    ASSERT_FALSE(token_products_bf16());
    (y * up).sum().backward();
    const auto xd = x.detach().reshape({m, k});
    auto want_y = rounded(xd).matmul(rounded(w.detach()).t()) + b.detach().to(torch::kDouble);
    if (relu) want_y = want_y.clamp_min(0);
    EXPECT_LT(test::max_abs(y.detach().reshape({m, n}).to(torch::kDouble) - want_y), 1e-4) << "relu " << relu;
    auto dy = up.reshape({m, n});
    if (relu) dy = dy * y.detach().reshape({m, n}).gt(0);
    const auto want_dx = rounded(dy).matmul(rounded(w.detach()));
    EXPECT_LT(test::max_abs(x.grad().reshape({m, k}).to(torch::kDouble) - want_dx), 1e-4) << "relu " << relu;
    const auto want_dw = rounded(dy).t().matmul(rounded(xd));
    EXPECT_LT(test::max_abs(w.grad().to(torch::kDouble) - want_dw), 1e-3) << "relu " << relu;
    EXPECT_LT(test::max_abs(b.grad().to(torch::kDouble) - dy.to(torch::kDouble).sum(0)), 1e-4);
    // Not the float32 products: those differ from the rounded ones by far more.
    const auto fp32_y = xd.to(torch::kDouble).matmul(w.detach().to(torch::kDouble).t());
    EXPECT_GT(test::max_abs(y.detach().reshape({m, n}).to(torch::kDouble) -
                            (fp32_y + b.detach().to(torch::kDouble)).clamp_min(relu ? 0.0 : -1e30)),
              1e-3);
  }
}

TEST(TokenProduct, BlockTailInBf16StaysNearTheFloat32Reference) {
  if (!cpu_has_bf16_products()) GTEST_SKIP() << "no AMX bfloat16 tiles on this CPU";
  const int64_t b = 16, l = 17, e = 32, f = 64;
  const double se = 1.0 / std::sqrt(double(e)), sf = 1.0 / std::sqrt(double(f));
  std::vector<torch::Tensor> inputs{
      test::seeded_randn({b, l, e}, 1),  test::seeded_randn({b, l, e}, 2),      test::seeded_randn({e, e}, 3, se),
      test::seeded_randn({e}, 4, 0.1),   test::seeded_randn({e}, 5, 0.2, 1.0),  test::seeded_randn({e}, 6, 0.1),
      test::seeded_randn({f, e}, 7, se), test::seeded_randn({f}, 8, 0.1),       test::seeded_randn({e, f}, 9, sf),
      test::seeded_randn({e}, 10, 0.1),  test::seeded_randn({e}, 11, 0.2, 1.0), test::seeded_randn({e}, 12, 0.1)};
  const auto up = test::seeded_randn({b, l, e}, 13).to(torch::kFloat);
  const auto run = [&](int which) {
    std::vector<torch::Tensor> leaves;
    for (const auto& t : inputs) leaves.push_back(t.to(torch::kFloat).requires_grad_());
    const BlockTailWeights w{leaves[2], leaves[3], leaves[4], leaves[5],  leaves[6],
                             leaves[7], leaves[8], leaves[9], leaves[10], leaves[11]};
    torch::Tensor y;
    if (which == 0) {
      y = block_tail_reference(leaves[0], leaves[1], w, 1e-5);
    } else {
      const TokenProductsBf16Scope scope(which == 2);
      y = block_tail(leaves[0], leaves[1], w, 1e-5);
    }
    (y * up).sum().backward();
    std::vector<torch::Tensor> out{y.detach()};
    for (const auto& leaf : leaves) out.push_back(leaf.grad());
    return out;
  };
  const auto want = run(0), fp32 = run(1), bf16 = run(2);
  for (size_t i = 0; i < want.size(); ++i) {
    const double scale = std::max(1.0, test::max_abs(want[i]));
    // bfloat16 keeps 8 significant bits: relative errors of a few 2^-9 per product, summed over
    // up to 64 terms of mixed signs.
    EXPECT_LT(test::max_abs(bf16[i] - want[i]), 0.05 * scale) << "output/gradient " << i;
    EXPECT_LT(test::max_abs(fp32[i] - want[i]), 1e-3 * scale) << "output/gradient " << i;
  }
  EXPECT_GT(test::max_abs(bf16[0] - fp32[0]), 1e-4) << "the bfloat16 products were not taken";
}

TEST(TokenProduct, TheScopeNestsAndIsRefusedWithoutTiles) {
  EXPECT_FALSE(token_products_bf16());
  if (!cpu_has_bf16_products()) {
    EXPECT_THROW(TokenProductsBf16Scope(true), std::invalid_argument);
    return;
  }
  {
    const TokenProductsBf16Scope on(true);
    EXPECT_TRUE(token_products_bf16());
    {
      const TokenProductsBf16Scope off(false);
      EXPECT_FALSE(token_products_bf16());
    }
    EXPECT_TRUE(token_products_bf16());
  }
  EXPECT_FALSE(token_products_bf16());
}

}  // namespace token_product_test
}  // namespace ablenerf
