// The fused tail of a transformer block on the CPU (kernels/block_tail.h) against its plain
// LibTorch reference: the same values and the same gradients for every input, at the presets'
// shapes and at odd ones (one ray of one token, a tail chunk, widths that are not a multiple of the
// vector length, a residual shared by the batch); the reference itself against finite differences
// and against the LayerNorm identities it must satisfy; bad inputs refused naming the argument.
#include <gtest/gtest.h>

#include "kernels/block_tail.h"
#include "kernels/kernel_test_util.h"

namespace ablenerf {
namespace {

constexpr double kTailEps = 1e-5;

struct BlockTailCase {
  int64_t b, bx, l, e, f, chunk;
};

// Seeded parameters (LayerNorm scales around 1) in float64.
BlockTailWeights seeded_tail_weights(int64_t e, int64_t f, uint64_t seed) {
  const double s_e = 1.0 / std::sqrt(double(e)), s_f = 1.0 / std::sqrt(double(f));
  return {test::seeded_randn({e, e}, seed, s_e),       test::seeded_randn({e}, seed + 1, 0.1),
          test::seeded_randn({e}, seed + 2, 0.2, 1.0), test::seeded_randn({e}, seed + 3, 0.1),
          test::seeded_randn({f, e}, seed + 4, s_e),   test::seeded_randn({f}, seed + 5, 0.1),
          test::seeded_randn({e, f}, seed + 6, s_f),   test::seeded_randn({e}, seed + 7, 0.1),
          test::seeded_randn({e}, seed + 8, 0.2, 1.0), test::seeded_randn({e}, seed + 9, 0.1)};
}

std::vector<torch::Tensor> tail_weight_list(const BlockTailWeights& w) {
  return {w.out_weight, w.out_bias,      w.norm1_weight, w.norm1_bias,   w.ff_in_weight,
          w.ff_in_bias, w.ff_out_weight, w.ff_out_bias,  w.norm2_weight, w.norm2_bias};
}

BlockTailWeights tail_weights_from(const std::vector<torch::Tensor>& v, size_t first) {
  return {v[first],     v[first + 1], v[first + 2], v[first + 3], v[first + 4],
          v[first + 5], v[first + 6], v[first + 7], v[first + 8], v[first + 9]};
}

// Values and gradients of block_tail and of the reference (both float32) for one upstream gradient.
void compare_tail_with_reference(const BlockTailCase& c, uint64_t seed, CpuVectorForm form) {
  std::vector<torch::Tensor> inputs{test::seeded_randn({c.bx, c.l, c.e}, seed),
                                    test::seeded_randn({c.b, c.l, c.e}, seed + 1)};
  for (const auto& w : tail_weight_list(seeded_tail_weights(c.e, c.f, seed + 2))) inputs.push_back(w);
  const auto up = test::seeded_randn({c.b, c.l, c.e}, seed + 20).to(torch::kFloat);
  std::vector<torch::Tensor> got, want;
  for (auto* out : {&got, &want}) {
    std::vector<torch::Tensor> leaves;
    for (const auto& t : inputs) leaves.push_back(t.to(torch::kFloat).requires_grad_());
    const auto w = tail_weights_from(leaves, 2);
    const auto y = out == &got ? block_tail(leaves[0], leaves[1], w, kTailEps, c.chunk, form)
                               : block_tail_reference(leaves[0], leaves[1], w, kTailEps);
    (y * up).sum().backward();
    out->push_back(y.detach());
    for (const auto& leaf : leaves) out->push_back(leaf.grad());
  }
  // Each entry is a sum of a known number of terms of about unit scale: the output and the heads'
  // gradient of E and F (a row's products), the residual's gradient of those over the B / Bx rows
  // that share one residual row, the parameters' gradients of up to B L rows as well.
  const double row_terms = double(std::max(c.e, c.f));
  for (size_t i = 0; i < got.size(); ++i) {
    ASSERT_TRUE(got[i].defined()) << "gradient " << i;
    ASSERT_EQ(got[i].sizes(), want[i].sizes()) << i;
    const double terms = i == 0 || i == 2 ? row_terms
                         : i == 1         ? row_terms * double(c.b / c.bx)
                                          : std::max(row_terms, double(c.b * c.l));
    const double tol = 2e-6 * terms * std::max(1.0, test::max_abs(want[i])) + 1e-5;
    EXPECT_LT(test::max_abs(got[i] - want[i]), tol)
        << "output/gradient " << i << " b " << c.b << " bx " << c.bx << " l " << c.l << " e " << c.e << " f " << c.f
        << " chunk " << c.chunk << " form " << static_cast<int>(form);
  }
}

// Every instruction form this CPU runs (the scalar one always, the fallback of a CPU without
// AVX-512), on rows that fill whole vectors, leave a partial one (20) or none at all (13).
TEST(BlockTail, MatchesTheReferenceInValuesAndGradients) {
  int ran = 0;
  for (const CpuVectorForm form : {CpuVectorForm::Scalar, CpuVectorForm::Avx512}) {
    if (!cpu_vector_form_available(form)) continue;
    ++ran;
    uint64_t seed = 10;
    for (const BlockTailCase& c : std::vector<BlockTailCase>{
             {64, 64, 17, 32, 64, 0},  // the capture preset's AB block (a slice of 64 rays)
             {64, 1, 8, 32, 64, 0},    // its LE cross-attention: the LE's queries shared by every ray
             {9, 9, 17, 48, 96, 50},   // the demo preset's widths, a tail chunk of 3 rows
             {1, 1, 1, 32, 64, 0},     // one ray of one token
             {5, 1, 3, 20, 24, 4},     // widths off the vector length, shared residual across chunks
             {3, 3, 7, 13, 9, 1}})     // a chunk of one row
      compare_tail_with_reference(c, seed += 31, form);
  }
  EXPECT_GE(ran, 1);
}

TEST(BlockTail, ChunkSizeChangesNothingButRounding) {
  const auto x = test::seeded_randn({6, 17, 32}, 3).to(torch::kFloat);
  const auto heads = test::seeded_randn({6, 17, 32}, 4).to(torch::kFloat);
  BlockTailWeights w = seeded_tail_weights(32, 64, 5);
  for (auto* t : {&w.out_weight, &w.out_bias, &w.norm1_weight, &w.norm1_bias, &w.ff_in_weight, &w.ff_in_bias,
                  &w.ff_out_weight, &w.ff_out_bias, &w.norm2_weight, &w.norm2_bias})
    *t = t->to(torch::kFloat);
  const auto whole = block_tail(x, heads, w, kTailEps, 1000);
  for (const int64_t chunk : {1, 16, 17, 101})
    EXPECT_LT(test::max_abs(block_tail(x, heads, w, kTailEps, chunk) - whole), 1e-5);
  // Without gradients anywhere no graph is recorded.
  EXPECT_FALSE(whole.requires_grad());
}

// The reference against central finite differences in float64, for the residual, the heads and a
// weight of each layer.
TEST(BlockTail, ReferenceGradientsMatchFiniteDifferences) {
  std::vector<torch::Tensor> inputs{test::seeded_randn({1, 3, 6}, 41), test::seeded_randn({2, 3, 6}, 42)};
  for (const auto& w : tail_weight_list(seeded_tail_weights(6, 5, 43))) inputs.push_back(w);
  const auto up = test::seeded_randn({2, 3, 6}, 60);
  const test::ScalarFunction f = [&](const std::vector<torch::Tensor>& v) {
    return (block_tail_reference(v[0], v[1], tail_weights_from(v, 2), kTailEps) * up).sum();
  };
  const auto analytic = test::autograd_gradients(f, inputs);
  for (const size_t which : {size_t(0), size_t(1), size_t(2), size_t(4), size_t(6), size_t(9), size_t(10)}) {
    const auto numeric = test::numeric_gradient(f, inputs, which);
    EXPECT_LT(test::max_abs(analytic[which] - numeric), 1e-6 * std::max(1.0, test::max_abs(numeric))) << which;
  }
}

// With unit LayerNorm scales and zero shifts every output row has mean 0 and variance 1 (up to eps).
TEST(BlockTail, OutputRowsAreNormalised) {
  BlockTailWeights w = seeded_tail_weights(32, 64, 7);
  w.norm2_weight = torch::ones({32}, torch::kDouble);
  w.norm2_bias = torch::zeros({32}, torch::kDouble);
  for (auto* t : {&w.out_weight, &w.out_bias, &w.norm1_weight, &w.norm1_bias, &w.ff_in_weight, &w.ff_in_bias,
                  &w.ff_out_weight, &w.ff_out_bias, &w.norm2_weight, &w.norm2_bias})
    *t = t->to(torch::kFloat);
  const auto y = block_tail(test::seeded_randn({4, 17, 32}, 8).to(torch::kFloat),
                            test::seeded_randn({4, 17, 32}, 9).to(torch::kFloat), w, kTailEps);
  EXPECT_LT(test::max_abs(y.mean(-1)), 1e-5);
  EXPECT_LT(test::max_abs(y.var(-1, /*unbiased=*/false) - 1), 1e-3);
}

TEST(BlockTail, BadInputsAreRefusedNamingTheArgument) {
  BlockTailWeights w = seeded_tail_weights(8, 16, 1);
  for (auto* t : {&w.out_weight, &w.out_bias, &w.norm1_weight, &w.norm1_bias, &w.ff_in_weight, &w.ff_in_bias,
                  &w.ff_out_weight, &w.ff_out_bias, &w.norm2_weight, &w.norm2_bias})
    *t = t->to(torch::kFloat);
  const auto x = torch::zeros({2, 3, 8}), heads = torch::zeros({2, 3, 8});
  test::expect_error_naming([&] { block_tail(torch::zeros({2, 4, 8}), heads, w, kTailEps); }, "block_tail: x");
  test::expect_error_naming([&] { block_tail(x, torch::zeros({2, 3}), w, kTailEps); }, "block_tail: heads");
  auto bad = w;
  bad.ff_out_weight = torch::zeros({8, 15});
  test::expect_error_naming([&] { block_tail(x, heads, bad, kTailEps); }, "ff_out_weight");
  bad = w;
  bad.norm2_bias = torch::zeros({7});
  test::expect_error_naming([&] { block_tail(x, heads, bad, kTailEps); }, "norm2_bias");
  test::expect_error_naming([&] { block_tail(x.to(torch::kDouble), heads, w, kTailEps); }, "CPU float32");
  test::expect_error_naming([&] { block_tail(x, heads, w, kTailEps, -1); }, "chunk_rows");
}

}  // namespace
}  // namespace ablenerf
