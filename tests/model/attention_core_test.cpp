// attention_core (threaded small products + hand-written backward) against the plain autograd
// formula softmax(Q K^T * scale + mask) V: same values and same gradients to float tolerance.
#include <gtest/gtest.h>

#include "model/ab_transformer.h"
#include "model/attention_core.h"

namespace ablenerf {
namespace {

constexpr int64_t kBatch = 48;  // enough matrices to be split across threads
constexpr int64_t kTokens = 7, kHeadDim = 5;
constexpr double kScale = 0.4;

torch::Tensor reference(const torch::Tensor& q, const torch::Tensor& k, const torch::Tensor& v,
                        const torch::Tensor& mask) {
  auto s = torch::matmul(q, k.transpose(1, 2)) * kScale;
  if (mask.defined()) s = s + mask;
  return torch::matmul(torch::softmax(s, -1), v);
}

void compare(const torch::Tensor& mask, int64_t lq) {
  torch::manual_seed(1);
  const auto q0 = torch::randn({kBatch, lq, kHeadDim}, torch::kFloat64);
  const auto k0 = torch::randn({kBatch, kTokens, kHeadDim}, torch::kFloat64);
  const auto v0 = torch::randn({kBatch, kTokens, kHeadDim}, torch::kFloat64);
  const auto upstream = torch::randn({kBatch, lq, kHeadDim}, torch::kFloat64);
  std::vector<torch::Tensor> got, want;
  for (auto* out : {&got, &want}) {
    auto q = q0.clone().requires_grad_(), k = k0.clone().requires_grad_(), v = v0.clone().requires_grad_();
    const auto o = out == &got ? attention_core(q, k, v, mask, kScale) : reference(q, k, v, mask);
    (o * upstream).sum().backward();
    *out = {o.detach(), q.grad(), k.grad(), v.grad()};
  }
  for (size_t i = 0; i < got.size(); ++i) EXPECT_TRUE(torch::allclose(got[i], want[i], 1e-10, 1e-12)) << i;
}

TEST(AttentionCore, MaskedSelfAttentionMatchesAutograd) {
  compare(ray_attention_mask(kTokens - 1, torch::TensorOptions().dtype(torch::kFloat64)), kTokens);
}

TEST(AttentionCore, UnmaskedCrossAttentionMatchesAutograd) { compare(torch::Tensor(), 3); }

TEST(AttentionCore, InferenceModeGivesTheSameValues) {
  torch::manual_seed(2);
  const auto q = torch::randn({kBatch, kTokens, kHeadDim}), k = torch::randn({kBatch, kTokens, kHeadDim});
  const auto v = torch::randn({kBatch, kTokens, kHeadDim});
  const auto want = reference(q, k, v, torch::Tensor());
  c10::InferenceMode guard;
  EXPECT_TRUE(torch::allclose(attention_core(q, k, v, torch::Tensor(), kScale), want, 1e-5, 1e-6));
}

}  // namespace
}  // namespace ablenerf
