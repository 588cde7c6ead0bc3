// The CPU attention kernels over packed projections (kernels/packed_attention.h) against the plain
// per-head autograd formula softmax(Q K^T * scale + mask) V: same values and same gradients, in
// float64 to 1e-10 and in float32 to float tolerance, for self-attention with the causal mask
// and for cross-attention with per-ray and with shared (batch-1) queries, on rays short enough for
// the register-blocked products and long enough for BLAS; and with the first query's row of
// probabilities as a second output carrying a gradient of its own.
#include <gtest/gtest.h>

#include <limits>

#include "kernels/kernel_test_util.h"
#include "kernels/packed_attention.h"
#include "test_util.h"

namespace ablenerf {
namespace {

constexpr int64_t kBatch = 24, kHeads = 3, kHeadDim = 4, kWidth = kHeads * kHeadDim;  // 72 products
constexpr int64_t kTokens = 7;
constexpr double kScale = 0.4;

// The heads of one call: H heads of dh.
struct Heads {
  int64_t count = kHeads, dim = kHeadDim;
  int64_t width() const { return count * dim; }
};

// Heads of a packed (B, L, C) tensor at columns [offset, offset + E): (B, H, L, dh).
torch::Tensor heads_of(const torch::Tensor& x, int64_t offset, Heads h = {}) {
  return x.narrow(2, offset, h.width()).reshape({x.size(0), x.size(1), h.count, h.dim}).transpose(1, 2);
}

// The ray mask over n tokens, additive: row 0 (the ray token) sees every column, row i >= 1 sees
// columns 0..i. Built here so that this suite needs nothing from the model.
torch::Tensor ray_mask(int64_t n, torch::ScalarType t = torch::kFloat) {
  auto blocked = torch::ones({n, n}, torch::kBool).triu(1);
  blocked[0].fill_(false);
  return torch::zeros({n, n}, t).masked_fill(blocked, -std::numeric_limits<double>::infinity());
}

// The attention's output (B, Lq, E) and its first query's probabilities (B, H, Lk).
struct Reference {
  torch::Tensor out, row0;
};

Reference reference_with_row0(const torch::Tensor& q_src, const torch::Tensor& kv_src, int64_t k_off, int64_t v_off,
                              const torch::Tensor& mask, Heads h = {}) {
  const auto q = heads_of(q_src, 0, h), k = heads_of(kv_src, k_off, h), v = heads_of(kv_src, v_off, h);
  auto s = torch::matmul(q, k.transpose(-2, -1)) * kScale;
  if (mask.defined()) s = s + mask;
  const auto p = torch::softmax(s, -1);
  const auto o = torch::matmul(p, v);  // (B, H, Lq, dh)
  return {o.transpose(1, 2).reshape({kv_src.size(0), q_src.size(1), h.width()}), p.select(2, 0)};
}

torch::Tensor reference(const torch::Tensor& q_src, const torch::Tensor& kv_src, int64_t k_off, int64_t v_off,
                        const torch::Tensor& mask, Heads h = {}) {
  return reference_with_row0(q_src, kv_src, k_off, v_off, mask, h).out;
}

struct Case {
  torch::Tensor q, kv;  // kv undefined = self-attention (q holds Q, K, V)
  torch::Tensor mask;
  Heads heads = {};
  CpuVectorForm form = cpu_best_vector_form();
};

// Values and gradients of the kernel and of the reference for the same upstream gradient; then
// again through the kernels that also return the first query's row (per-ray queries only), with an
// upstream gradient on the row too, as the ray token's attention losses give it.
void compare(const Case& c, double tol) {
  const bool self = !c.kv.defined();
  const int64_t e = c.heads.width();
  const bool row_form = self || c.q.size(0) == c.kv.size(0);
  for (const bool with_row0 : {false, true}) {
    if (with_row0 && !row_form) continue;
    SCOPED_TRACE(with_row0 ? "with the first query's row" : "output only");
    std::vector<torch::Tensor> got, want;
    for (auto* out : {&got, &want}) {
      auto q = c.q.clone().requires_grad_();
      auto kv = self ? torch::Tensor() : c.kv.clone().requires_grad_();
      Reference o;
      if (out == &got && with_row0) {
        const PackedAttention r = self ? packed_self_attention_row0(q, c.heads.count, c.mask, kScale, c.form)
                                       : packed_cross_attention_row0(q, kv, c.heads.count, kScale, c.form);
        o = {r.out, r.row0};
      } else if (out == &got) {
        o.out = self ? packed_self_attention(q, c.heads.count, c.mask, kScale, c.form)
                     : packed_cross_attention(q, kv, c.heads.count, kScale, c.form);
      } else {
        o = self ? reference_with_row0(q, q, e, 2 * e, c.mask, c.heads)
                 : reference_with_row0(q, kv, 0, e, c.mask, c.heads);
      }
      auto gen = at::detail::createCPUGenerator(3);
      const auto upstream = torch::randn(o.out.sizes(), gen, o.out.options());
      auto loss = (o.out * upstream).sum();
      if (with_row0) loss = loss + (o.row0 * torch::randn(o.row0.sizes(), gen, o.row0.options())).sum();
      loss.backward();
      *out = {o.out.detach(), q.grad()};
      if (with_row0) out->push_back(o.row0.detach());
      if (!self) out->push_back(kv.grad());
    }
    ASSERT_EQ(got.size(), want.size());
    for (size_t i = 0; i < got.size(); ++i) {
      ASSERT_EQ(got[i].sizes(), want[i].sizes()) << i;
      EXPECT_LT((got[i] - want[i]).abs().max().item<double>(), tol) << "output/gradient " << i;
    }
  }
}

torch::Tensor rnd(std::vector<int64_t> sizes, torch::ScalarType t, uint64_t seed) {
  return test::seeded_randn(std::move(sizes), seed).to(t);
}

TEST(PackedAttention, MaskedSelfAttentionMatchesReference) {
  if (!packed_attention_available(torch::zeros({1}, torch::kDouble))) GTEST_SKIP() << "no CBLAS in this process";
  const test::IntraOpThreads threads(2);  // the products split across threads on any machine
  const auto mask = ray_mask(kTokens, torch::kDouble);
  compare({rnd({kBatch, kTokens, 3 * kWidth}, torch::kDouble, 1), {}, mask}, 1e-10);
  compare({rnd({kBatch, kTokens, 3 * kWidth}, torch::kDouble, 2), {}, {}}, 1e-10);  // bidirectional
  compare({rnd({kBatch, kTokens, 3 * kWidth}, torch::kFloat, 3), {}, mask.to(torch::kFloat)}, 1e-4);
}

// 17 tokens (the demo preset's: score rows of two whole float vectors and one left over) and 70
// (above the register-blocked products' 64, so through BLAS).
TEST(PackedAttention, LongerRaysMatchReference) {
  if (!packed_attention_available(torch::zeros({1}, torch::kDouble))) GTEST_SKIP() << "no CBLAS in this process";
  for (const int64_t tokens : {17, 70}) {
    const auto mask = ray_mask(tokens, torch::kDouble);
    compare({rnd({4, tokens, 3 * kWidth}, torch::kDouble, 20 + tokens), {}, mask}, 1e-10);
    compare({rnd({4, tokens, 3 * kWidth}, torch::kFloat, 21 + tokens), {}, mask.to(torch::kFloat)}, 1e-4);
    compare(
        {rnd({4, 3, kWidth}, torch::kFloat, 22 + tokens), rnd({4, tokens, 2 * kWidth}, torch::kFloat, 23 + tokens), {}},
        1e-4);
  }
}

TEST(PackedAttention, CrossAttentionMatchesReference) {
  if (!packed_attention_available(torch::zeros({1}, torch::kDouble))) GTEST_SKIP() << "no CBLAS in this process";
  const test::IntraOpThreads threads(2);  // the products split across threads on any machine
  // Per-ray queries, and queries shared by the batch (their gradient sums over rays).
  compare({rnd({kBatch, 3, kWidth}, torch::kDouble, 4), rnd({kBatch, kTokens, 2 * kWidth}, torch::kDouble, 5), {}},
          1e-10);
  compare({rnd({1, 5, kWidth}, torch::kDouble, 6), rnd({kBatch, kTokens, 2 * kWidth}, torch::kDouble, 7), {}}, 1e-10);
  compare({rnd({1, 5, kWidth}, torch::kFloat, 8), rnd({kBatch, kTokens, 2 * kWidth}, torch::kFloat, 9), {}}, 1e-4);
}

// Heads of at most 64 floats, where a CPU with AVX-512 computes each (ray, head) in registers: the
// presets' shapes (2 heads of 16 or 24 over 17 tokens, 8 shared queries), heads that are not whole
// 16-float vectors (7, 24, 40) and odd ones (one
// token, one key, a query count that is not a multiple of the four rows taken at once, 64 tokens
// = four whole score vectors, 65 = past the vector form, so through the products), in both forms.
TEST(PackedAttention, WholeVectorHeadsMatchReferenceInEveryForm) {
  for (const CpuVectorForm form : {CpuVectorForm::Scalar, CpuVectorForm::Avx512}) {
    if (!cpu_vector_form_available(form)) continue;
    SCOPED_TRACE(form == CpuVectorForm::Avx512 ? "avx512" : "scalar");
    uint64_t seed = 100;
    for (const Heads h :
         {Heads{2, 16}, Heads{2, 24}, Heads{1, 7}, Heads{1, 32}, Heads{2, 40}, Heads{3, 48}, Heads{1, 64}}) {
      for (const int64_t tokens : {1, 2, 5, 17, 33, 64, 65}) {
        SCOPED_TRACE("heads " + std::to_string(h.count) + " x " + std::to_string(h.dim) + ", tokens " +
                     std::to_string(tokens));
        const int64_t e = h.width();
        const auto mask = ray_mask(tokens);
        compare({rnd({3, tokens, 3 * e}, torch::kFloat, ++seed), {}, mask, h, form}, 2e-5);
        compare({rnd({3, tokens, 3 * e}, torch::kFloat, ++seed), {}, {}, h, form}, 2e-5);
        compare({rnd({1, 9, e}, torch::kFloat, ++seed), rnd({3, tokens, 2 * e}, torch::kFloat, ++seed), {}, h, form},
                2e-5);
        compare({rnd({3, 6, e}, torch::kFloat, ++seed), rnd({3, tokens, 2 * e}, torch::kFloat, ++seed), {}, h, form},
                2e-5);
      }
    }
  }
}

// The vector form over more rays than one thread takes (the items split between threads).
TEST(PackedAttention, WholeVectorHeadsSplitAcrossThreads) {
  const test::IntraOpThreads threads(2);
  const Heads h{2, 16};
  compare({rnd({64, 17, 3 * h.width()}, torch::kFloat, 200), {}, ray_mask(17), h}, 2e-5);
  compare({rnd({1, 9, h.width()}, torch::kFloat, 201), rnd({64, 17, 2 * h.width()}, torch::kFloat, 202), {}, h}, 2e-5);
}

// Sixteen rays to a vector (heads of 16 or 24, at most 32 tokens, at least 16 rays): whole groups
// and a last group with one ray or fifteen, one token to 32 (33 goes back to the items), the ray
// mask (whose blocked keys are skipped) and none, cross-attention with shared and per-ray queries,
// with the first query's row and its gradient; against the reference formula in float32.
TEST(PackedAttention, RayLanesMatchReference) {
  if (!cpu_vector_form_available(CpuVectorForm::Avx512)) GTEST_SKIP() << "no AVX-512 on this CPU";
  uint64_t seed = 300;
  for (const int64_t rays : {16, 17, 31, 48}) {
    for (const int64_t tokens : {1, 5, 17, 32, 33}) {
      for (const Heads h : {Heads{2, 16}, Heads{1, 24}}) {
        const int64_t e = h.width();
        SCOPED_TRACE(std::to_string(rays) + " rays, " + std::to_string(tokens) + " tokens, heads of " +
                     std::to_string(h.dim));
        const auto mask = ray_mask(tokens);
        compare({rnd({rays, tokens, 3 * e}, torch::kFloat, ++seed), {}, mask, h, CpuVectorForm::Avx512}, 2e-5);
        compare({rnd({rays, tokens, 3 * e}, torch::kFloat, ++seed), {}, {}, h, CpuVectorForm::Avx512}, 2e-5);
        compare({rnd({1, 8, e}, torch::kFloat, ++seed),
                 rnd({rays, tokens, 2 * e}, torch::kFloat, ++seed),
                 {},
                 h,
                 CpuVectorForm::Avx512},
                2e-5);
        compare({rnd({rays, 3, e}, torch::kFloat, ++seed),
                 rnd({rays, tokens, 2 * e}, torch::kFloat, ++seed),
                 {},
                 h,
                 CpuVectorForm::Avx512},
                2e-5);
      }
    }
  }
  // A mask with finite entries beside the blocked ones: added to the scores as they are.
  const Heads h{2, 16};
  const int64_t e = h.width();
  auto mask = ray_mask(9);
  mask[3][1] = -1.5f;
  mask[0][4] = 0.75f;
  compare({rnd({20, 9, 3 * e}, torch::kFloat, 399), {}, mask, h, CpuVectorForm::Avx512}, 2e-5);
}

TEST(PackedAttention, InferenceModeGivesTheSameValues) {
  if (!packed_attention_available(torch::zeros({1}))) GTEST_SKIP() << "no CBLAS in this process";
  const test::IntraOpThreads threads(2);  // the products split across threads on any machine
  const auto qkv = rnd({kBatch, kTokens, 3 * kWidth}, torch::kFloat, 10);
  const auto mask = ray_mask(kTokens);
  const auto want = reference(qkv, qkv, kWidth, 2 * kWidth, mask);
  c10::InferenceMode guard;
  EXPECT_LT((packed_self_attention(qkv, kHeads, mask, kScale) - want).abs().max().item<double>(), 1e-5);
  // Heads of 16 (the vector form where the CPU runs it).
  const Heads h{2, 16};
  const auto wide = rnd({kBatch, 17, 3 * h.width()}, torch::kFloat, 11);
  const auto wide_mask = ray_mask(17);
  const auto wide_want = reference(wide, wide, h.width(), 2 * h.width(), wide_mask, h);
  EXPECT_LT((packed_self_attention(wide, h.count, wide_mask, kScale) - wide_want).abs().max().item<double>(), 1e-5);
  // The first query's row beside it, as the resampler reads it when rendering.
  const auto r = packed_self_attention_row0(wide, h.count, wide_mask, kScale);
  const auto row_want = reference_with_row0(wide, wide, h.width(), 2 * h.width(), wide_mask, h).row0;
  EXPECT_LT((r.out - wide_want).abs().max().item<double>(), 1e-5);
  EXPECT_LT((r.row0 - row_want).abs().max().item<double>(), 1e-6);
}

TEST(PackedAttention, AvailableOnlyForCpuFloatingPoint) {
  EXPECT_FALSE(packed_attention_available(torch::zeros({1}, torch::kInt)));
  EXPECT_FALSE(packed_attention_available(torch::zeros({1}, torch::kHalf)));
}

}  // namespace
}  // namespace ablenerf
