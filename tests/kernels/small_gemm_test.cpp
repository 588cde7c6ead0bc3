// The register-blocked small products (kernels/small_gemm.h) against LibTorch's matmul on the same
// operands: every width from 1 to 40 columns (whole blocks of four, three, two and one vectors and
// the leftover columns, for 8 floats and 4 doubles per vector), odd and even row counts, A as stored
// and transposed, operands inside wider rows (strides larger than the widths), in float64 to 1e-12
// and in float32 to float tolerance; C's elements outside the m x n block are left untouched. Every
// instruction form this CPU runs (AVX-512, AVX2, the baseline one), and the one small_gemm picks.
#include <gtest/gtest.h>

#include <cstdint>
#include <tuple>
#include <vector>

#include "kernels/kernel_test_util.h"
#include "kernels/small_gemm.h"

namespace ablenerf {
namespace {

struct Shape {
  int64_t m, n, k;
  bool trans_a;
};

// Runs one product with padded strides and checks it against the reference; returns the max error.
// The form to run (nothing: the one small_gemm picks).
template <class T>
double check(const Shape& s, uint64_t seed, double tol, c10::optional<SmallGemmForm> form) {
  const auto dtype = std::is_same<T, float>::value ? torch::kFloat : torch::kDouble;
  constexpr int64_t kPad = 3;  // extra elements at the end of every row of A, B and C
  const int64_t a_rows = s.trans_a ? s.k : s.m, a_cols = s.trans_a ? s.m : s.k;
  const auto a_full = test::seeded_randn({a_rows, a_cols + kPad}, seed).to(dtype);
  const auto b_full = test::seeded_randn({s.k, s.n + kPad}, seed + 1).to(dtype);
  const double alpha = 0.75;
  const auto a = a_full.narrow(1, 0, a_cols), b = b_full.narrow(1, 0, s.n);
  const auto want = (s.trans_a ? a.t() : a).to(torch::kDouble).matmul(b.to(torch::kDouble)) * alpha;

  const T sentinel = T(12345);
  auto c_full = torch::full({s.m, s.n + kPad}, sentinel, dtype);
  const auto product = [&](auto... args) {
    if (form) return small_gemm_in(*form, args...);
    small_gemm(args...);
  };
  product(s.trans_a, s.m, s.n, s.k, T(alpha), a_full.template data_ptr<T>(), a_cols + kPad,
          b_full.template data_ptr<T>(), s.n + kPad, c_full.template data_ptr<T>(), s.n + kPad);
  const auto got = c_full.narrow(1, 0, s.n).to(torch::kDouble);
  EXPECT_TRUE(c_full.narrow(1, s.n, kPad).eq(sentinel).all().template item<bool>())
      << "wrote outside C: m " << s.m << " n " << s.n << " k " << s.k;
  const double err = (got - want).abs().max().template item<double>();
  EXPECT_LT(err, tol) << "m " << s.m << " n " << s.n << " k " << s.k << " trans_a " << s.trans_a;
  return err;
}

std::vector<Shape> shapes() {
  std::vector<Shape> out;
  // Up to 72 columns: whole blocks of one to four vectors of 16 floats, 8 or 4 doubles, and leftovers.
  for (int64_t n = 1; n <= 72; ++n)
    for (const int64_t m : {1, 2, 5, 17})
      for (const bool t : {false, true}) out.push_back({m, n, n % 7 + 1, t});
  // The attention core at the demo preset: S = Q K^T (17 x 17 x 24), O = P V (17 x 24 x 17), the
  // transposed-A products of the backward (17 x 24 x 17), and the largest size allowed.
  out.push_back({17, 17, 24, false});
  out.push_back({17, 24, 17, false});
  out.push_back({17, 24, 17, true});
  out.push_back({kSmallGemmMaxDim, kSmallGemmMaxDim, kSmallGemmMaxDim, true});
  out.push_back({kSmallGemmMaxDim, kSmallGemmMaxDim, kSmallGemmMaxDim, false});
  // The token layers of a fused block (kernels/block_tail.h): a chunk of rows through a projection,
  // and a weight's gradient over a chunk (a long reduction with A transposed).
  out.push_back({300, 96, 32, false});
  out.push_back({32, 64, 257, true});
  return out;
}

// The picked form, then every form this CPU runs.
std::vector<c10::optional<SmallGemmForm>> forms() {
  std::vector<c10::optional<SmallGemmForm>> out{c10::nullopt};
  for (const auto f : {SmallGemmForm::Avx512, SmallGemmForm::Avx2, SmallGemmForm::Baseline})
    if (small_gemm_form_available(f)) out.emplace_back(f);
  return out;
}

TEST(SmallGemm, Float64MatchesMatmul) {
  for (const auto& form : forms()) {
    uint64_t seed = 10;
    for (const auto& s : shapes()) check<double>(s, seed += 2, 1e-12, form);
  }
}

TEST(SmallGemm, Float32MatchesMatmul) {
  for (const auto& form : forms()) {
    uint64_t seed = 500;
    double worst = 0;
    // float32 operands; the reference multiplies them in float64: the error is the float32
    // accumulation's, a few ulps of sqrt(k)-sized sums.
    for (const auto& s : shapes()) worst = std::max(worst, check<float>(s, seed += 2, 2e-5 * double(s.k), form));
    EXPECT_GT(worst, 0.0) << "float32 sums agreeing exactly with float64 ones: the float path did not run";
  }
}

TEST(SmallGemm, PicksTheWidestFormTheCpuRuns) {
  const auto best = small_gemm_best_form();
  EXPECT_TRUE(small_gemm_form_available(best));
  EXPECT_TRUE(small_gemm_form_available(SmallGemmForm::Baseline));
  if (small_gemm_form_available(SmallGemmForm::Avx512)) EXPECT_EQ(best, SmallGemmForm::Avx512);
  if (!small_gemm_form_available(SmallGemmForm::Avx2)) EXPECT_EQ(best, SmallGemmForm::Baseline);
}

TEST(SmallGemm, FitsOnlySmallPositiveSizes) {
  EXPECT_TRUE(small_gemm_fits(17, 17, 24));
  EXPECT_TRUE(small_gemm_fits(kSmallGemmMaxDim, 1, kSmallGemmMaxDim));
  EXPECT_FALSE(small_gemm_fits(kSmallGemmMaxDim + 1, 1, 1));
  EXPECT_FALSE(small_gemm_fits(97, 64, 97));
  EXPECT_FALSE(small_gemm_fits(0, 4, 4));
}

// Inside one tile, and over several with partial ones at both edges (rows and columns not a
// multiple of the tile).
TEST(SmallGemm, TransposeIntoMatchesTranspose) {
  for (const auto& [rows, cols, stride] : {std::tuple<int64_t, int64_t, int64_t>{5, 7, 9}, {37, 50, 53}}) {
    const auto src = test::seeded_randn({rows, stride}, 77).to(torch::kFloat);  // the first `cols` of each row used
    std::vector<float> dst(static_cast<size_t>(cols * rows));
    transpose_into(src.data_ptr<float>(), rows, cols, stride, dst.data());
    const auto got = torch::from_blob(dst.data(), {cols, rows}, torch::kFloat);
    EXPECT_TRUE(got.equal(src.narrow(1, 0, cols).t().contiguous())) << rows << " x " << cols;
  }
}

// The buffer starts on a cache line at every size, keeps its memory when asked for less, and
// holds what is written to it.
TEST(SmallGemm, AlignedFloatsStartOnACacheLine) {
  AlignedFloats buffer;
  for (const size_t n : {size_t(1), size_t(17), size_t(1000), size_t(10), size_t(100000)}) {
    buffer.resize(n);
    ASSERT_NE(buffer.data(), nullptr);
    EXPECT_EQ(reinterpret_cast<uintptr_t>(buffer.data()) % 64, 0u) << n;
    for (size_t i = 0; i < n; ++i) buffer.data()[i] = static_cast<float>(i);
    EXPECT_EQ(buffer.data()[n - 1], static_cast<float>(n - 1));
  }
  float* kept = buffer.data();
  buffer.resize(5);
  EXPECT_EQ(buffer.data(), kept);
}

}  // namespace
}  // namespace ablenerf
