// The step's losses on the attention in one CPU node (kernels/attention_losses_cpu.h) against the
// plain reference, train/regularisers.h's LibTorch functions: the same values and the same gradients
// for the attention and the proposal's weights, each proposal role sending its gradient to its own
// input only; in float64 to 1e-12 and in float32 to float tolerance; odd shapes (one ray, one
// interval, more target than proposal intervals), posts the two sets share, a ray whose attention
// sums below attention_distribution's floor, no proposal; bad shapes refused naming the argument;
// and ray_loss giving the same loss and gradients through either path.
#include <gtest/gtest.h>

#include "kernels/attention_losses_cpu.h"
#include "kernels/kernel_test_util.h"
#include "train/grad_accumulation.h"
#include "train/regularisers.h"
#include "train/train_config.h"

namespace ablenerf {
namespace {

// Sorted fence-posts (rays, intervals + 1) in [0, 1], starting at 0 and ending at 1.
torch::Tensor sorted_posts(int64_t rays, int64_t intervals, uint64_t seed) {
  const auto steps = test::seeded_randn({rays, intervals}, seed).abs() + 0.05;
  const auto c = torch::cat({torch::zeros({rays, 1}, torch::kDouble), torch::cumsum(steps, 1)}, 1);
  return c / c.select(1, intervals).unsqueeze(1);
}

struct Inputs {
  torch::Tensor w, st, sp, wp;
};

// Attention weights that sum below 1 per ray (the ray token keeps the rest), the proposal's weights
// positive; ray 0's proposal posts include two of its target posts exactly.
Inputs make_inputs(int64_t rays, int64_t m, int64_t n, uint64_t seed, torch::ScalarType dtype) {
  Inputs in;
  in.w = (torch::softmax(test::seeded_randn({rays, m + 1}, seed), 1).slice(1, 1)).contiguous();
  in.st = sorted_posts(rays, m, seed + 1);
  in.sp = sorted_posts(rays, n, seed + 2);
  in.wp = test::seeded_randn({rays, n}, seed + 3).abs() * (2.0 / static_cast<double>(n));
  if (m >= 2 && n >= 3) {
    in.sp[0][1] = in.st[0][1];
    in.sp[0][n - 1] = in.st[0][m - 1];
  }
  for (auto* t : {&in.w, &in.st, &in.sp, &in.wp}) *t = t->to(dtype);
  return in;
}

struct Result {
  torch::Tensor proposal, attention, distortion;  // values
  torch::Tensor dw, dwp;                          // gradients of the weighted sum below
};

// The three terms, then the gradient of 0.7 proposal + 1.3 attention + 0.4 distortion.
template <class Terms>
Result run(const Inputs& in, bool proposal, bool distortion, Terms&& terms) {
  auto w = in.w.clone().requires_grad_();
  auto wp = in.wp.clone().requires_grad_();
  const AttentionLosses t = terms(w, wp);
  torch::Tensor total = torch::zeros({}, in.w.options());
  if (proposal) total = total + 0.7 * t.proposal + 1.3 * t.attention;
  if (distortion) total = total + 0.4 * t.distortion;
  total.backward();
  Result r;
  if (proposal) r.proposal = t.proposal.detach(), r.attention = t.attention.detach();
  if (distortion) r.distortion = t.distortion.detach();
  r.dw = w.grad().defined() ? w.grad() : torch::zeros_like(w);
  r.dwp = wp.grad().defined() ? wp.grad() : torch::zeros_like(wp);
  return r;
}

Result fused(const Inputs& in, bool proposal, bool distortion) {
  return run(in, proposal, distortion, [&](const torch::Tensor& w, const torch::Tensor& wp) {
    return attention_losses_cpu(w, in.st, in.sp, wp, proposal, distortion);
  });
}

Result reference(const Inputs& in, bool proposal, bool distortion) {
  return run(in, proposal, distortion, [&](const torch::Tensor& w, const torch::Tensor& wp) {
    AttentionLosses t;
    if (proposal) {
      t.proposal = proposal_loss(in.sp, wp, in.st, attention_distribution(w).detach()).sum();
      t.attention = proposal_loss(in.sp, wp.detach(), in.st, attention_distribution(w)).sum();
    }
    if (distortion) t.distortion = distortion_loss(attention_distribution(w), in.st).sum();
    return t;
  });
}

void expect_close(const torch::Tensor& got, const torch::Tensor& want, double tol, const std::string& what) {
  ASSERT_EQ(got.sizes(), want.sizes()) << what;
  const double scale = std::max(1.0, test::max_abs(want));
  EXPECT_LE(test::max_abs(got - want), tol * scale) << what << "\ngot " << got << "\nwant " << want;
}

void compare(const Inputs& in, bool proposal, bool distortion, double tol) {
  const Result got = fused(in, proposal, distortion), want = reference(in, proposal, distortion);
  if (proposal) {
    expect_close(got.proposal, want.proposal, tol, "proposal value");
    expect_close(got.attention, want.attention, tol, "attention value");
  }
  if (distortion) expect_close(got.distortion, want.distortion, tol, "distortion value");
  expect_close(got.dw, want.dw, tol, "attention gradient");
  expect_close(got.dwp, want.dwp, tol, "proposal weights' gradient");
}

TEST(AttentionLossesCpu, MatchesTheReferenceInFloat64) {
  const Inputs in = make_inputs(9, 16, 32, 11, torch::kDouble);
  compare(in, true, true, 1e-12);
  compare(in, true, false, 1e-12);
  compare(in, false, true, 1e-12);
}

TEST(AttentionLossesCpu, MatchesTheReferenceInFloat32) {
  const Inputs in = make_inputs(128, 16, 32, 21, torch::kFloat);
  compare(in, true, true, 2e-5);
}

TEST(AttentionLossesCpu, OddShapes) {
  compare(make_inputs(1, 16, 32, 31, torch::kDouble), true, true, 1e-12);  // one ray
  compare(make_inputs(3, 1, 1, 41, torch::kDouble), true, true, 1e-12);    // one interval each
  compare(make_inputs(4, 40, 5, 51, torch::kDouble), true, true, 1e-12);   // more targets than proposal
}

TEST(AttentionLossesCpu, TheProposalLossIsNotZeroAndEachRoleFeedsItsOwnInput) {
  // The weights are built so that the proposal under-bounds the attention somewhere (the loss would
  // otherwise be 0 and say nothing about its gradient).
  Inputs in = make_inputs(5, 16, 32, 61, torch::kDouble);
  in.wp = in.wp * 0.1;
  const Result both = fused(in, true, false);
  ASSERT_GT(both.proposal.item<double>(), 1e-3);
  EXPECT_GT(test::max_abs(both.dw), 1e-3);
  EXPECT_GT(test::max_abs(both.dwp), 1e-3);
  // Only the proposal role: no gradient reaches the attention.
  auto w = in.w.clone().requires_grad_();
  auto wp = in.wp.clone().requires_grad_();
  attention_losses_cpu(w, in.st, in.sp, wp, true, false).proposal.backward();
  EXPECT_FALSE(w.grad().defined() && test::max_abs(w.grad()) > 0);
  EXPECT_GT(test::max_abs(wp.grad()), 1e-3);
  compare(in, true, false, 1e-12);
}

TEST(AttentionLossesCpu, AttentionBelowTheFloor) {
  Inputs in = make_inputs(3, 16, 32, 71, torch::kDouble);
  in.w[1] = in.w[1] * 1e-8;  // sums to under 1e-6: attention_distribution divides by the floor
  ASSERT_LT(in.w[1].sum().item<double>(), 1e-6);
  compare(in, true, true, 1e-10);
}

TEST(AttentionLossesCpu, WithoutAProposal) {
  const Inputs in = make_inputs(4, 16, 32, 81, torch::kDouble);
  auto w = in.w.clone().requires_grad_();
  const AttentionLosses t = attention_losses_cpu(w, in.st, torch::Tensor(), torch::Tensor(), false, true);
  EXPECT_FALSE(t.proposal.defined());
  EXPECT_NEAR(t.distortion.item<double>(), distortion_loss(attention_distribution(in.w), in.st).sum().item<double>(),
              1e-12);
}

TEST(AttentionLossesCpu, BadShapesAreRefusedNamingTheArgument) {
  const Inputs in = make_inputs(4, 16, 32, 91, torch::kDouble);
  try {
    attention_losses_cpu(in.w, in.st.slice(1, 0, 16), in.sp, in.wp, true, true);
    FAIL() << "a short s_t was accepted";
  } catch (const c10::Error& e) {
    EXPECT_NE(std::string(e.what_without_backtrace()).find("attention_losses_cpu: s_t"), std::string::npos)
        << e.what_without_backtrace();
  }
  try {
    attention_losses_cpu(in.w, in.st, in.sp.slice(1, 0, 20), in.wp, true, true);
    FAIL() << "a short s_p was accepted";
  } catch (const c10::Error& e) {
    EXPECT_NE(std::string(e.what_without_backtrace()).find("attention_losses_cpu: s_p"), std::string::npos)
        << e.what_without_backtrace();
  }
  EXPECT_FALSE(attention_losses_cpu_available(in.w, in.st, in.sp, in.wp.to(torch::kFloat)));
  EXPECT_FALSE(attention_losses_cpu_available(in.w, in.st.requires_grad_(), in.sp, in.wp));
}

TEST(AttentionLossesCpu, RayLossIsTheSameThroughEitherPath) {
  const Inputs in = make_inputs(6, 16, 32, 101, torch::kDouble);
  TrainConfig tc;
  tc.distortion_weight = 0.01;
  tc.proposal_weight = 1.0;
  tc.proposal_attention_weight = 0.01;
  tc.coarse_weight = 0;
  const auto target = test::seeded_randn({6, 3}, 5).sigmoid();
  const auto rgb = test::seeded_randn({6, 3}, 6).sigmoid();
  std::vector<torch::Tensor> losses, grads;
  for (const bool fused_path : {false, true}) {
    ModelOutput out;
    out.rgb_fine = rgb;
    out.fine_weights = in.w.clone().requires_grad_();
    out.fine_s = in.st;
    out.proposal_s = in.sp;
    out.proposal_weights = in.wp.clone().requires_grad_();
    const LossTerms t = ray_loss(out, target, tc, 6, torch::scalar_tensor(0.5, torch::kDouble), fused_path);
    t.loss.backward();
    losses.push_back(t.terms);
    grads.push_back(out.fine_weights.grad());
    grads.push_back(out.proposal_weights.grad());
  }
  expect_close(losses[1], losses[0], 1e-12, "loss terms");
  EXPECT_GT(losses[0][kTermProposal].item<double>(), 0);
  EXPECT_GT(losses[0][kTermDistortion].item<double>(), 0);
  expect_close(grads[2], grads[0], 1e-12, "attention gradient");
  expect_close(grads[3], grads[1], 1e-12, "proposal weights' gradient");
}

}  // namespace
}  // namespace ablenerf
