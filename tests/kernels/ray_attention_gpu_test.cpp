// The fused CUDA ray attention (kernels/ray_attention.h) against its plain LibTorch reference:
// values, the ray token's probability row and the gradient of the packed qkv for a random
// upstream gradient, masked and unmasked, float32 (to ~1e-5 of the result's scale) and bfloat16
// (to 2e-2 of it; the reference then runs in float32 on the same bf16 values), over batch sizes
// and token counts around the kernels' tile edges; saturated scores stay finite; bad arguments
// are refused with an error.
#include <gtest/gtest.h>

#ifdef ABLENERF_CUDA_KERNELS  // CUDA builds only: the CPU LibTorch has no CUDA headers
#include <ATen/cuda/CUDAContext.h>
#endif

#include <sstream>
#include <string>

#include "kernels/ray_attention.h"

namespace ablenerf {
namespace {

constexpr int64_t kHeads = 3, kHeadDim = 64, kWidth = kHeads * kHeadDim;

#define REQUIRE_CUDA() \
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device"

struct Case {
  torch::ScalarType dtype;
  bool masked;
  int64_t batch, tokens;
  double spread = 1.0;      // standard deviation of the qkv entries
  double tol_factor = 1.0;  // looser tolerances where large scores amplify summation-order differences
  std::string name() const {
    std::ostringstream s;
    s << (dtype == torch::kFloat ? "fp32" : "bf16") << (masked ? " masked" : " open") << " B=" << batch
      << " L=" << tokens << " spread=" << spread;
    return s.str();
  }
};

// |got - want| relative to the scale of want (its largest magnitude).
double relative_error(const torch::Tensor& got, const torch::Tensor& want) {
  const double scale = std::max(want.abs().max().item<double>(), 1e-6);
  return (got.to(torch::kFloat) - want.to(torch::kFloat)).abs().max().item<double>() / scale;
}

bool finite(const torch::Tensor& x) { return torch::isfinite(x).all().item<bool>(); }

void check_against_reference(const Case& c, uint64_t seed) {
  SCOPED_TRACE(c.name());
  torch::manual_seed(seed);
  const auto cuda = torch::TensorOptions().device(torch::kCUDA);
  // Inputs representable in the tested dtype, so that the reference sees exactly the same values.
  const auto qkv = (torch::randn({c.batch, c.tokens, 3 * kWidth}, cuda) * c.spread).to(c.dtype);
  const auto upstream = torch::randn({c.batch, c.tokens, kWidth}, cuda).to(c.dtype);

  auto x = qkv.clone().requires_grad_(true);
  const auto got = ray_attention(x, kHeads, c.masked);
  ASSERT_EQ(got.out.sizes(), (std::vector<int64_t>{c.batch, c.tokens, kWidth}));
  ASSERT_EQ(got.row0.sizes(), (std::vector<int64_t>{c.batch, kHeads, c.tokens}));
  EXPECT_EQ(got.out.scalar_type(), c.dtype);
  EXPECT_EQ(got.row0.scalar_type(), torch::kFloat);
  EXPECT_FALSE(got.row0.requires_grad());
  torch::autograd::backward({got.out}, {upstream});
  const auto grad = x.grad();
  ASSERT_TRUE(grad.defined());
  EXPECT_EQ(grad.scalar_type(), c.dtype);

  auto xr = qkv.to(torch::kFloat).clone().requires_grad_(true);
  const auto want = ray_attention_reference(xr, kHeads, c.masked);
  torch::autograd::backward({want.out}, {upstream.to(torch::kFloat)});

  EXPECT_TRUE(finite(got.out));
  EXPECT_TRUE(finite(got.row0));
  EXPECT_TRUE(finite(grad));
  const bool fp32 = c.dtype == torch::kFloat;
  const double tol = (fp32 ? 2e-5 : 2e-2) * c.tol_factor;
  EXPECT_LT(relative_error(got.out, want.out), tol);
  EXPECT_LT(relative_error(grad, xr.grad()), tol);
  // Probabilities: both sides compute them in fp32 from the same values.
  EXPECT_LT((got.row0 - want.row0).abs().max().item<double>(), (fp32 ? 1e-5 : 1e-4) * c.tol_factor);
  EXPECT_LT((got.row0.sum(-1) - 1).abs().max().item<double>(), 1e-4);
}

TEST(RayAttentionGpu, MatchesReferenceOverBatchesAndTokenCounts) {
  REQUIRE_CUDA();
  uint64_t seed = 1;
  for (const auto dtype : {torch::kFloat, torch::kBFloat16})
    for (const bool masked : {true, false})
      for (const int64_t batch : {1, 3, 1000})
        for (const int64_t tokens : {97, 5, 128}) check_against_reference({dtype, masked, batch, tokens}, seed++);
}

// Token counts at and around the 4-row (fp32) and 16-row (bf16) tile edges.
TEST(RayAttentionGpu, MatchesReferenceAtTileEdges) {
  REQUIRE_CUDA();
  uint64_t seed = 100;
  for (const auto dtype : {torch::kFloat, torch::kBFloat16})
    for (const bool masked : {true, false})
      for (const int64_t tokens : {1, 2, 15, 16, 17, 33, 64, 112, 127})
        check_against_reference({dtype, masked, 3, tokens}, seed++);
}

// Large scores (standard deviation ~36: near one-hot rows, exp underflow for most columns): still
// finite and equal to the reference, to tolerances widened for the scores' fp32 rounding (an error
// of 1e-5 in a score of 100 moves its probability by 1e-3). Every row sees column 0, so no row is
// ever fully blocked.
TEST(RayAttentionGpu, SaturatedScoresStayFinite) {
  REQUIRE_CUDA();
  uint64_t seed = 200;
  for (const auto dtype : {torch::kFloat, torch::kBFloat16})
    for (const bool masked : {true, false})
      check_against_reference({dtype, masked, 64, 97, 6.0, dtype == torch::kFloat ? 50.0 : 2.5}, seed++);
}

// Views: a non-contiguous slice and a contiguous view whose start is not 16-byte aligned.
TEST(RayAttentionGpu, AcceptsViewsAndDifferentiatesIntoThem) {
  REQUIRE_CUDA();
  torch::manual_seed(300);
  const auto cuda = torch::TensorOptions().device(torch::kCUDA);
  for (const auto dtype : {torch::kFloat, torch::kBFloat16}) {
    const int64_t batch = 5, tokens = 97, n = batch * tokens * 3 * kWidth;
    auto wide = torch::randn({batch, tokens, 3 * kWidth + 4}, cuda).to(dtype).requires_grad_(true);
    auto shifted = torch::randn({n + 1}, cuda).to(dtype).requires_grad_(true);
    const auto views = {wide.narrow(2, 2, 3 * kWidth), shifted.narrow(0, 1, n).view({batch, tokens, 3 * kWidth})};
    for (const auto& v : views) {
      const auto got = ray_attention(v, kHeads, true);
      const auto want = ray_attention_reference(v.detach().to(torch::kFloat), kHeads, true);
      EXPECT_LT(relative_error(got.out, want.out), dtype == torch::kFloat ? 2e-5 : 2e-2);
      got.out.sum().backward();
    }
    // The gradient reached the base tensors, and only the viewed part of them.
    EXPECT_TRUE(finite(wide.grad()));
    EXPECT_EQ(wide.grad().narrow(2, 0, 2).abs().max().item<double>(), 0.0);
    EXPECT_GT(wide.grad().abs().max().item<double>(), 0.0);
    EXPECT_EQ(shifted.grad()[0].item<double>(), 0.0);
    EXPECT_GT(shifted.grad().abs().max().item<double>(), 0.0);
  }
}

TEST(RayAttentionGpu, EmptyBatch) {
  REQUIRE_CUDA();
  const auto qkv = torch::zeros({0, 97, 3 * kWidth}, torch::TensorOptions().device(torch::kCUDA));
  const auto r = ray_attention(qkv, kHeads, true);
  EXPECT_EQ(r.out.sizes(), (std::vector<int64_t>{0, 97, kWidth}));
  EXPECT_EQ(r.row0.sizes(), (std::vector<int64_t>{0, kHeads, 97}));
}

// More than 2^31 elements in qkv and its gradient: 64-bit offsets, checked on the first and the
// last rays against the reference run on those rays alone.
TEST(RayAttentionGpu, BatchBeyondInt32Offsets) {
  REQUIRE_CUDA();
#ifdef ABLENERF_CUDA_KERNELS
  const auto* props = at::cuda::getCurrentDeviceProperties();
  if (props->totalGlobalMem < (size_t(32) << 30)) GTEST_SKIP() << "needs a GPU with >= 32 GB";
#else
  GTEST_SKIP() << "built without CUDA kernels";
#endif
  torch::manual_seed(400);
  const int64_t batch = 40000, tokens = 97;  // 40000 * 97 * 576 > 2^31
  const auto cuda = torch::TensorOptions().device(torch::kCUDA).dtype(torch::kBFloat16);
  auto x = torch::randn({batch, tokens, 3 * kWidth}, cuda).requires_grad_(true);
  const auto upstream = torch::randn({batch, tokens, kWidth}, cuda);
  const auto got = ray_attention(x, kHeads, true);
  torch::autograd::backward({got.out}, {upstream});
  for (const int64_t first : {int64_t(0), batch - 2}) {
    auto xr = x.detach().narrow(0, first, 2).to(torch::kFloat).requires_grad_(true);
    const auto want = ray_attention_reference(xr, kHeads, true);
    torch::autograd::backward({want.out}, {upstream.narrow(0, first, 2).to(torch::kFloat)});
    EXPECT_LT(relative_error(got.out.narrow(0, first, 2), want.out), 2e-2) << first;
    EXPECT_LT(relative_error(x.grad().narrow(0, first, 2), xr.grad()), 2e-2) << first;
    EXPECT_LT((got.row0.narrow(0, first, 2) - want.row0).abs().max().item<double>(), 1e-4) << first;
  }
}

TEST(RayAttentionGpu, RefusesUnsupportedArguments) {
  REQUIRE_CUDA();
  const auto cuda = torch::TensorOptions().device(torch::kCUDA);
  EXPECT_THROW(ray_attention(torch::zeros({2, 129, 3 * kWidth}, cuda), kHeads, true), c10::Error);  // L > 128
  EXPECT_THROW(ray_attention(torch::zeros({2, 97, 3 * 96}, cuda), kHeads, true), c10::Error);       // dh = 32
  EXPECT_THROW(ray_attention(torch::zeros({2, 97, 3 * kWidth}, cuda.dtype(torch::kDouble)), kHeads, true), c10::Error);
  EXPECT_THROW(ray_attention(torch::zeros({2, 97, 3 * kWidth}, cuda.dtype(torch::kHalf)), kHeads, true), c10::Error);
  EXPECT_THROW(ray_attention(torch::zeros({2, 97, 3 * kWidth}), kHeads, true), c10::Error);  // CPU
  EXPECT_THROW(ray_attention(torch::zeros({97, 3 * kWidth}, cuda), kHeads, true), c10::Error);
  EXPECT_THROW(ray_attention(torch::zeros({2, 97, 3 * kWidth}, cuda), 5, true), c10::Error);
  EXPECT_THROW(ray_attention(torch::zeros({2, 0, 3 * kWidth}, cuda), kHeads, true), c10::Error);
}

}  // namespace
}  // namespace ablenerf
