// The plain LibTorch reference of the fused ray attention (kernels/ray_attention.h), which the CUDA
// kernels are tested against, checked here on the CPU: against a float64 computation written
// with explicit loops (row 0 sees every token, row i >= 1 sees tokens 0..i), including the ray
// token's probability row; its autograd gradient against central finite differences; and the
// argument checks.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <vector>

#include "kernels/ray_attention.h"

namespace ablenerf {
namespace {

torch::Tensor random_qkv(int64_t batch, int64_t tokens, int64_t width, torch::ScalarType dtype, uint64_t seed,
                         double spread = 1.0) {
  auto gen = at::detail::createCPUGenerator(seed);
  return (torch::randn({batch, tokens, 3 * width}, gen, torch::kDouble) * spread).to(dtype);
}

// out (B, L, E) and row0 (B, H, L) from explicit loops in float64.
struct LoopResult {
  torch::Tensor out, row0;
};

LoopResult attention_by_loops(const torch::Tensor& qkv_in, int64_t heads, bool masked) {
  const auto qkv = qkv_in.to(torch::kDouble).contiguous();
  const int64_t batch = qkv.size(0), tokens = qkv.size(1), width = qkv.size(2) / 3, dh = width / heads;
  const auto x = qkv.accessor<double, 3>();
  auto out = torch::zeros({batch, tokens, width}, torch::kDouble);
  auto row0 = torch::zeros({batch, heads, tokens}, torch::kDouble);
  auto o = out.accessor<double, 3>();
  auto r0 = row0.accessor<double, 3>();
  const double scale = 1.0 / std::sqrt(double(dh));
  std::vector<double> p(tokens);
  for (int64_t b = 0; b < batch; ++b)
    for (int64_t h = 0; h < heads; ++h)
      for (int64_t i = 0; i < tokens; ++i) {
        const int64_t last = masked && i > 0 ? i : tokens - 1;
        double top = -std::numeric_limits<double>::infinity();
        for (int64_t j = 0; j <= last; ++j) {
          double s = 0;
          for (int64_t d = 0; d < dh; ++d) s += x[b][i][h * dh + d] * x[b][j][width + h * dh + d];
          p[j] = s * scale;
          top = std::max(top, p[j]);
        }
        double sum = 0;
        for (int64_t j = 0; j <= last; ++j) sum += p[j] = std::exp(p[j] - top);
        for (int64_t j = 0; j <= last; ++j) {
          p[j] /= sum;
          if (i == 0) r0[b][h][j] = p[j];
          for (int64_t d = 0; d < dh; ++d) o[b][i][h * dh + d] += p[j] * x[b][j][2 * width + h * dh + d];
        }
      }
  return {out, row0};
}

double max_abs_diff(const torch::Tensor& a, const torch::Tensor& b) {
  return (a.to(torch::kDouble) - b.to(torch::kDouble)).abs().max().item<double>();
}

TEST(RayAttentionReference, MatchesExplicitLoops) {
  struct Shape {
    int64_t batch, tokens, heads, dh;
  };
  for (const Shape s : {Shape{3, 7, 2, 4}, Shape{2, 97, 3, 64}, Shape{1, 1, 1, 8}})
    for (const bool masked : {true, false}) {
      const auto qkv = random_qkv(s.batch, s.tokens, s.heads * s.dh, torch::kDouble, 11 + s.tokens, 1.5);
      const auto want = attention_by_loops(qkv, s.heads, masked);
      const auto got = ray_attention_reference(qkv, s.heads, masked);
      ASSERT_EQ(got.out.sizes(), want.out.sizes());
      ASSERT_EQ(got.row0.sizes(), want.row0.sizes());
      EXPECT_EQ(got.out.scalar_type(), torch::kDouble);
      EXPECT_LT(max_abs_diff(got.out, want.out), 1e-12) << "L=" << s.tokens << " masked=" << masked;
      EXPECT_LT(max_abs_diff(got.row0, want.row0), 1e-12) << "L=" << s.tokens << " masked=" << masked;
    }
}

TEST(RayAttentionReference, Float32AndBfloat16AccumulateInFloat32) {
  const auto qkv = random_qkv(4, 97, 192, torch::kFloat, 5);
  const auto want = attention_by_loops(qkv, 3, true);
  const auto got = ray_attention_reference(qkv, 3, true);
  EXPECT_EQ(got.out.scalar_type(), torch::kFloat);
  EXPECT_EQ(got.row0.scalar_type(), torch::kFloat);
  EXPECT_LT(max_abs_diff(got.out, want.out), 1e-5);
  EXPECT_LT(max_abs_diff(got.row0, want.row0), 1e-6);

  // bf16 in, bf16 out: the float32 result of the bf16 values, rounded once.
  const auto q16 = qkv.to(torch::kBFloat16);
  const auto want16 = attention_by_loops(q16, 3, true);
  const auto got16 = ray_attention_reference(q16, 3, true);
  EXPECT_EQ(got16.out.scalar_type(), torch::kBFloat16);
  EXPECT_EQ(got16.row0.scalar_type(), torch::kFloat);
  EXPECT_LT(max_abs_diff(got16.out, want16.out.to(torch::kBFloat16)), 1e-2);
  EXPECT_LT(max_abs_diff(got16.row0, want16.row0), 1e-6);
}

// Behaviour of the mask itself: row i >= 1 cannot see tokens after i, row 0 sees all of them.
TEST(RayAttentionReference, MaskHidesLaterTokensFromAllButTheRayToken) {
  const int64_t tokens = 6, width = 8, heads = 2;
  const auto qkv = random_qkv(2, tokens, width, torch::kDouble, 3);
  auto changed = qkv.clone();
  changed.narrow(1, 3, tokens - 3).narrow(2, width, 2 * width).mul_(-4.0).add_(2.0);  // K, V of tokens 3..5
  const auto before = ray_attention_reference(qkv, heads, true).out;
  const auto after = ray_attention_reference(changed, heads, true).out;
  EXPECT_LT(max_abs_diff(before.narrow(1, 1, 2), after.narrow(1, 1, 2)), 1e-15);  // rows 1, 2
  EXPECT_GT(max_abs_diff(before.select(1, 0), after.select(1, 0)), 1e-3);         // the ray token
  EXPECT_GT(max_abs_diff(before.narrow(1, 3, 3), after.narrow(1, 3, 3)), 1e-3);   // rows 3..5
  const auto open_before = ray_attention_reference(qkv, heads, false).out;
  const auto open_after = ray_attention_reference(changed, heads, false).out;
  EXPECT_GT(max_abs_diff(open_before.select(1, 1), open_after.select(1, 1)), 1e-3);
}

TEST(RayAttentionReference, GradientMatchesFiniteDifferences) {
  const int64_t batch = 2, tokens = 5, width = 8, heads = 2;
  for (const bool masked : {true, false}) {
    const auto qkv = random_qkv(batch, tokens, width, torch::kDouble, masked ? 21 : 22);
    auto gen = at::detail::createCPUGenerator(masked ? 31 : 32);
    const auto weight = torch::randn({batch, tokens, width}, gen, torch::kDouble);
    const auto loss = [&](const torch::Tensor& x) {
      return (ray_attention_reference(x, heads, masked).out * weight).sum();
    };
    auto x = qkv.clone().requires_grad_(true);
    loss(x).backward();
    const auto grad = x.grad();

    auto fd = torch::zeros_like(qkv);
    const double eps = 1e-6;
    auto flat = qkv.clone().view(-1);
    auto fd_flat = fd.view(-1);
    torch::NoGradGuard no_grad;
    for (int64_t e = 0; e < flat.numel(); ++e) {
      const double keep = flat[e].item<double>();
      flat[e] = keep + eps;
      const double up = loss(flat.view(qkv.sizes())).item<double>();
      flat[e] = keep - eps;
      const double down = loss(flat.view(qkv.sizes())).item<double>();
      flat[e] = keep;
      fd_flat[e] = (up - down) / (2 * eps);
    }
    EXPECT_LT(max_abs_diff(grad, fd), 1e-8) << "masked=" << masked;
    EXPECT_GT(grad.abs().max().item<double>(), 1e-2);  // not vacuous
    if (masked) {
      // K and V of the last token, seen only by the ray token and by the last row, still get
      // gradient.
      EXPECT_GT(grad.select(1, tokens - 1).narrow(1, width, 2 * width).abs().max().item<double>(), 1e-4);
    }
  }
}

TEST(RayAttentionReference, RejectsMalformedInput) {
  const auto qkv = torch::zeros({2, 5, 24});
  EXPECT_THROW(ray_attention_reference(torch::zeros({5, 24}), 2, true), c10::Error);
  EXPECT_THROW(ray_attention_reference(qkv, 5, true), c10::Error);  // 24 is not 3 * 5 * dh
  EXPECT_THROW(ray_attention_reference(qkv, 0, true), c10::Error);
  EXPECT_THROW(ray_attention_reference(torch::zeros({2, 5, 24}, torch::kLong), 2, true), c10::Error);
  EXPECT_THROW(ray_attention_reference(torch::Tensor(), 2, true), c10::Error);
}

// The fused kernels take CUDA tensors only; builds without them refuse every call.
TEST(RayAttention, RefusesCpuTensors) { EXPECT_THROW(ray_attention(torch::zeros({1, 97, 576}), 3, true), c10::Error); }

}  // namespace
}  // namespace ablenerf
