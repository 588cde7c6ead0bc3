// The bfloat16-operand products (kernels/bf16_gemm.h) against LibTorch: both operands converted
// to LibTorch's bfloat16 (round to nearest, ties to even) and multiplied in float64, so that only
// the float32 sums' rounding is left (bounded by k float32 roundings of the sum of |products|).
// Every form this CPU runs (AMX, the reference loops), at the transformer's shapes,
// single rows and columns, widths that are not a multiple of a tile or a vector, strided A and C
// (C's elements outside m x n untouched), B packed from W^T and from W; the rounding function
// against LibTorch's and at its edges (ties, NaN, infinity, subnormals); bad arguments refused.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <utility>
#include <vector>

#include "kernels/bf16_gemm.h"
#include "kernels/kernel_test_util.h"

namespace ablenerf {
namespace bf16_gemm_test {

uint16_t bits_of(float x) { return bf16_bits(x); }
float from_bits(uint32_t u) {
  float x;
  std::memcpy(&x, &u, sizeof(x));
  return x;
}

TEST(Bf16Gemm, RoundingMatchesLibTorchAndItsEdges) {
  const auto x = test::seeded_randn({4096}, 3, 10.0).to(torch::kFloat);
  const auto want = x.to(torch::kBFloat16).to(torch::kFloat);
  for (int64_t i = 0; i < x.numel(); ++i)
    ASSERT_EQ(bf16_round(x[i].item<float>()), want[i].item<float>()) << "element " << i;
  EXPECT_EQ(bits_of(1.0f), 0x3f80);
  EXPECT_EQ(bits_of(from_bits(0x3f808000u)), 0x3f80);  // a tie: to the even neighbour (down)
  EXPECT_EQ(bits_of(from_bits(0x3f818000u)), 0x3f82);  // a tie: to the even neighbour (up)
  EXPECT_EQ(bits_of(from_bits(0x3f808001u)), 0x3f81);  // just above a tie: up
  EXPECT_EQ(bits_of(std::numeric_limits<float>::infinity()), 0x7f80);
  EXPECT_EQ(bits_of(std::numeric_limits<float>::max()), 0x7f80);  // rounds to infinity
  EXPECT_TRUE(std::isnan(bf16_round(std::numeric_limits<float>::quiet_NaN())));
  EXPECT_TRUE(std::isnan(bf16_round(from_bits(0x7f800001u))));  // a NaN whose payload would round away
  EXPECT_EQ(bits_of(from_bits(0x00000001u)), 0x0000);           // subnormals to signed zero
  EXPECT_EQ(bits_of(from_bits(0x807fffffu)), 0x8000);
}

struct Shape {
  int64_t m, k, n;
};

// C = bf16(A) bf16(B) for one form; B packed from W^T (n x k weight) or from B itself.
void check(Bf16GemmForm form, const Shape& s, bool b_from_weight, uint64_t seed) {
  constexpr int64_t kPad = 5;
  const auto a_full = test::seeded_randn({s.m, s.k + kPad}, seed).to(torch::kFloat);
  const auto a = a_full.narrow(1, 0, s.k);
  const auto b = test::seeded_randn({s.k, s.n}, seed + 1).to(torch::kFloat);
  Bf16Operand packed;
  if (b_from_weight) {
    const auto w = b.t().contiguous();  // (n, k)
    packed.pack(w.data_ptr<float>(), s.k, s.n, 1, s.k, form);
  } else {
    packed.pack(b.data_ptr<float>(), s.k, s.n, s.n, 1, form);
  }
  const float sentinel = 12345.f;
  auto c_full = torch::full({s.m, s.n + kPad}, sentinel);
  bf16_gemm_in(form, s.m, a_full.data_ptr<float>(), s.k + kPad, packed, c_full.data_ptr<float>(), s.n + kPad);

  const auto ar = a.to(torch::kBFloat16).to(torch::kDouble), br = b.to(torch::kBFloat16).to(torch::kDouble);
  const auto want = ar.matmul(br);
  const auto bound = ar.abs().matmul(br.abs()) * (s.k * std::ldexp(1.0, -23)) + 1e-30;
  const auto got = c_full.narrow(1, 0, s.n).to(torch::kDouble);
  const auto excess = ((got - want).abs() - bound).max().item<double>();
  EXPECT_LE(excess, 0.0) << bf16_gemm_form_name(form) << " m " << s.m << " k " << s.k << " n " << s.n;
  EXPECT_TRUE(c_full.narrow(1, s.n, kPad).eq(sentinel).all().item<bool>())
      << bf16_gemm_form_name(form) << " wrote outside C: m " << s.m << " k " << s.k << " n " << s.n;
  // Not float32 products: the unrounded operands' product differs by far more than the bound.
  if (s.k >= 8) {
    const auto exact = a.to(torch::kDouble).matmul(b.to(torch::kDouble));
    EXPECT_GT(((got - exact).abs() - bound).max().item<double>(), 0.0) << "operands not rounded to bfloat16";
  }
}

std::vector<Shape> shapes() {
  return {{1, 1, 1},      {1, 32, 16},    {5, 3, 7},      {4, 32, 64},   {33, 32, 96}, {31, 33, 50},
          {37, 48, 17},   {64, 96, 32},   {16, 64, 16},   {65, 64, 48},  {2, 130, 72}, {100, 17, 100},
          {2176, 32, 96}, {2176, 64, 32}, {2176, 96, 32}, {97, 192, 576}};
}

std::vector<Bf16GemmForm> forms() {
  std::vector<Bf16GemmForm> out;
  for (const auto f : {Bf16GemmForm::Amx, Bf16GemmForm::Reference})
    if (bf16_gemm_form_available(f)) out.push_back(f);
  return out;
}

TEST(Bf16Gemm, EveryFormMatchesTheRoundedProduct) {
  uint64_t seed = 10;
  for (const auto form : forms()) {
    SCOPED_TRACE(bf16_gemm_form_name(form));
    for (const auto& s : shapes())
      for (const bool from_weight : {false, true}) check(form, s, from_weight, seed += 2);
  }
}

// C = bf16(A)^T bf16(B), A (k x m) and B (k x n) inside wider rows: a weight's gradient.
void check_at(Bf16GemmForm form, const Shape& s, uint64_t seed) {
  constexpr int64_t kPad = 3;
  const auto a_full = test::seeded_randn({s.k, s.m + kPad}, seed).to(torch::kFloat);
  const auto b_full = test::seeded_randn({s.k, s.n + kPad}, seed + 1).to(torch::kFloat);
  Bf16Operand packed;
  packed.pack(b_full.data_ptr<float>(), s.k, s.n, s.n + kPad, 1, form);
  const float sentinel = -777.f;
  auto c_full = torch::full({s.m, s.n + kPad}, sentinel);
  bf16_gemm_at_in(form, s.m, a_full.data_ptr<float>(), s.m + kPad, packed, c_full.data_ptr<float>(), s.n + kPad);
  const auto ar = a_full.narrow(1, 0, s.m).to(torch::kBFloat16).to(torch::kDouble);
  const auto br = b_full.narrow(1, 0, s.n).to(torch::kBFloat16).to(torch::kDouble);
  const auto want = ar.t().matmul(br);
  const auto bound = ar.abs().t().matmul(br.abs()) * (s.k * std::ldexp(1.0, -23)) + 1e-30;
  const auto got = c_full.narrow(1, 0, s.n).to(torch::kDouble);
  EXPECT_LE(((got - want).abs() - bound).max().item<double>(), 0.0)
      << bf16_gemm_form_name(form) << " transposed A: m " << s.m << " k " << s.k << " n " << s.n;
  EXPECT_TRUE(c_full.narrow(1, s.n, kPad).eq(sentinel).all().item<bool>())
      << bf16_gemm_form_name(form) << " transposed A wrote outside C";
}

TEST(Bf16Gemm, TransposedAMatchesTheRoundedProduct) {
  uint64_t seed = 300;
  for (const auto form : forms()) {
    SCOPED_TRACE(bf16_gemm_form_name(form));
    // (m, k, n): the weight gradients dW = dy^T x of the presets' layers over a slice's tokens, and
    // odd sizes (a single token, outputs off a tile's 16 rows, tokens off its 32).
    for (const Shape& s : std::vector<Shape>{{96, 2176, 32},
                                             {64, 2176, 32},
                                             {144, 2176, 48},
                                             {1, 1, 1},
                                             {17, 1, 5},
                                             {33, 45, 17},
                                             {16, 32, 16},
                                             {50, 97, 70}})
      check_at(form, s, seed += 2);
  }
}

TEST(Bf16Gemm, EveryPackingFormGivesTheSameBits) {
  // Rows contiguous, columns contiguous (W^T) and neither, at odd sizes.
  for (const auto& [k, n] :
       std::vector<std::pair<int64_t, int64_t>>{{1, 1}, {3, 5}, {32, 16}, {33, 17}, {96, 32}, {47, 70}}) {
    const auto b = test::seeded_randn({k * n * 2}, static_cast<uint64_t>(k * 100 + n)).to(torch::kFloat);
    for (const auto& [rs, cs] : std::vector<std::pair<int64_t, int64_t>>{{n, 1}, {1, k}, {2 * n, 2}}) {
      Bf16Operand want, got;
      want.pack(b.data_ptr<float>(), k, n, rs, cs, Bf16GemmForm::Reference);
      const size_t count = static_cast<size_t>(want.k_padded() * want.n_padded());
      for (size_t i = 0; i < count; ++i) {
        const int64_t q = static_cast<int64_t>(i) / 2 / want.n_padded(),
                      j = static_cast<int64_t>(i) / 2 % want.n_padded();
        const int64_t p = 2 * q + static_cast<int64_t>(i % 2);
        const uint16_t expect = p < k && j < n ? bf16_bits(b[p * rs + j * cs].item<float>()) : 0;
        ASSERT_EQ(want.data()[i], expect) << "reference packing, k " << k << " n " << n << " index " << i;
      }
      for (const auto form : forms()) {
        got.pack(b.data_ptr<float>(), k, n, rs, cs, form);
        ASSERT_EQ(std::memcmp(got.data(), want.data(), count * sizeof(uint16_t)), 0)
            << bf16_gemm_form_name(form) << " k " << k << " n " << n << " strides " << rs << ", " << cs;
      }
    }
  }
}

TEST(Bf16Gemm, TheBestFormIsTheWidestAvailable) {
  const auto best = bf16_gemm_best_form();
  EXPECT_TRUE(bf16_gemm_form_available(best));
  if (bf16_gemm_form_available(Bf16GemmForm::Amx)) {
    EXPECT_EQ(best, Bf16GemmForm::Amx);
  }
  EXPECT_EQ(cpu_has_bf16_products(), best != Bf16GemmForm::Reference);
  // The reference form (any CPU) runs through the dispatching entry point as well.
  check(Bf16GemmForm::Reference, {7, 40, 20}, true, 99);
}

TEST(Bf16Gemm, RepackingToASmallerShapeKeepsNoOldValues) {
  Bf16Operand packed;
  const auto big = test::seeded_randn({96, 96}, 5).to(torch::kFloat);
  packed.pack(big.data_ptr<float>(), 96, 96, 96, 1);
  for (const auto form : forms()) check(form, {9, 20, 10}, false, 7);  // fresh operands each
  const auto b = test::seeded_randn({20, 10}, 8).to(torch::kFloat);
  const auto a = test::seeded_randn({9, 20}, 9).to(torch::kFloat);
  packed.pack(b.data_ptr<float>(), 20, 10, 10, 1);
  EXPECT_EQ(packed.k_padded(), 32);
  EXPECT_EQ(packed.n_padded(), 16);
  for (const auto form : forms()) {
    auto c = torch::empty({9, 10});
    bf16_gemm_in(form, 9, a.data_ptr<float>(), 20, packed, c.data_ptr<float>(), 10);
    const auto want = a.to(torch::kBFloat16).to(torch::kDouble).matmul(b.to(torch::kBFloat16).to(torch::kDouble));
    EXPECT_LT((c.to(torch::kDouble) - want).abs().max().item<double>(), 1e-4) << bf16_gemm_form_name(form);
  }
}

TEST(Bf16Gemm, BadArgumentsAreRefusedNamingThem) {
  Bf16Operand packed;
  const auto b = torch::ones({8, 4});
  std::vector<float> a(64), c(64);
  try {
    bf16_gemm(2, a.data(), 4, packed, c.data(), 4);
    ADD_FAILURE() << "an unpacked B was taken";
  } catch (const c10::Error& e) {
    EXPECT_NE(std::string(e.what_without_backtrace()).find("bf16_gemm"), std::string::npos);
  }
  packed.pack(b.data_ptr<float>(), 8, 4, 4, 1);
  try {
    bf16_gemm(2, a.data(), 7, packed, c.data(), 4);
    ADD_FAILURE() << "lda < k was taken";
  } catch (const c10::Error& e) {
    const std::string what = e.what_without_backtrace();
    EXPECT_NE(what.find("bf16_gemm"), std::string::npos);
    EXPECT_NE(what.find("lda"), std::string::npos);
  }
  EXPECT_THROW(packed.pack(b.data_ptr<float>(), 0, 4, 4, 1), c10::Error);
}

}  // namespace bf16_gemm_test
}  // namespace ablenerf
