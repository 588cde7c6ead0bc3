// Stage 4: the transformer block against a plain per-head reference, the mask of docs/MODEL.md, section 4,
// causality of the AB transformer, and the initialisation of docs/MODEL.md, section 8.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>

#include "model/ab_transformer.h"
#include "model/attention.h"
#include "model/compute_config.h"
#include "model/resampler.h"

namespace ablenerf {
namespace {

constexpr int64_t kWidth = 192, kHeads = 3, kFF = 576;

torch::Tensor ref_layer_norm(const torch::Tensor& x, const torch::Tensor& g, const torch::Tensor& b) {
  const auto mean = x.mean(-1, true);
  const auto var = (x - mean).pow(2).mean(-1, true);  // biased, like LayerNorm
  return (x - mean) / torch::sqrt(var + 1e-5) * g + b;
}

// Multi-head attention of one ray with explicit loops over heads; mask is 0/-inf or undefined.
torch::Tensor ref_mha(const MultiHeadAttentionImpl& a, const torch::Tensor& q_in, const torch::Tensor& kv_in,
                      const torch::Tensor& mask) {
  const int64_t e = q_in.size(-1), dh = e / kHeads;
  const auto& w = a.in_proj_weight;
  const auto& bias = a.in_proj_bias;
  std::vector<torch::Tensor> heads;
  for (int64_t h = 0; h < kHeads; ++h) {
    auto rows = [&](int64_t block) {
      return std::make_pair(w.slice(0, block * e + h * dh, block * e + (h + 1) * dh),
                            bias.slice(0, block * e + h * dh, block * e + (h + 1) * dh));
    };
    const auto [wq, bq] = rows(0);
    const auto [wk, bk] = rows(1);
    const auto [wv, bv] = rows(2);
    const auto q = q_in.matmul(wq.t()) + bq, k = kv_in.matmul(wk.t()) + bk, v = kv_in.matmul(wv.t()) + bv;
    auto s = q.matmul(k.t()) / std::sqrt(static_cast<double>(dh));
    if (mask.defined()) s = s + mask;
    heads.push_back(torch::softmax(s, -1).matmul(v));
  }
  return torch::cat(heads, -1).matmul(a.out_proj->weight.t()) + a.out_proj->bias;
}

torch::Tensor ref_block(TransformerBlockImpl& blk, const torch::Tensor& q, const torch::Tensor& kv,
                        const torch::Tensor& mask) {
  const auto h = ref_layer_norm(q + ref_mha(*blk.attn, q, kv, mask), blk.norm1->weight, blk.norm1->bias);
  auto f = h.matmul(blk.ff_in->weight.t()) + blk.ff_in->bias;
  f = 0.5 * f * (1.0 + torch::erf(f / std::sqrt(2.0)));  // exact GELU
  f = f.matmul(blk.ff_out->weight.t()) + blk.ff_out->bias;
  return ref_layer_norm(h + f, blk.norm2->weight, blk.norm2->bias);
}

TEST(Attention, MaskPattern) {
  const auto m = ray_attention_mask(4);
  ASSERT_EQ(m.sizes(), (std::vector<int64_t>{5, 5}));
  for (int i = 0; i < 5; ++i)
    for (int j = 0; j < 5; ++j) {
      const bool allowed = i == 0 || j <= i;
      const double v = m[i][j].item<double>();
      if (allowed)
        EXPECT_EQ(v, 0.0) << i << j;
      else
        EXPECT_TRUE(std::isinf(v) && v < 0) << i << j;
    }
}

TEST(Attention, SelfBlockMatchesPerHeadReference) {
  torch::manual_seed(1);
  TransformerBlock blk(kWidth, kHeads, kFF);
  blk->to(torch::kDouble);
  {  // non-trivial biases and norms so that every parameter matters
    torch::NoGradGuard g;
    for (auto& p : blk->parameters()) p.add_(0.05 * torch::randn_like(p));
  }
  const int64_t b = 3, s = 8;
  const auto x = torch::randn({b, s + 1, kWidth}, torch::kDouble);
  const auto mask = ray_attention_mask(s, torch::kDouble);
  for (bool use_mask : {true, false}) {
    const auto m = use_mask ? mask : torch::Tensor();
    const auto out = blk->forward_self(x, m);
    for (int64_t r = 0; r < b; ++r)
      EXPECT_TRUE(torch::allclose(out[r], ref_block(*blk, x[r], x[r], m), 1e-10, 1e-10)) << r << use_mask;
  }
  // Float path too (what the model runs).
  blk->to(torch::kFloat);
  const auto xf = x.to(torch::kFloat);
  const auto out = blk->forward_self(xf, mask.to(torch::kFloat));
  EXPECT_LT((out[1] - ref_block(*blk, xf[1], xf[1], mask.to(torch::kFloat))).abs().max().item<double>(), 1e-5);
}

TEST(Attention, CrossBlockWithSharedQueriesMatchesReference) {
  torch::manual_seed(2);
  TransformerBlock blk(kWidth, kHeads, kFF);
  blk->to(torch::kDouble);
  const auto le = torch::randn({1, 5, kWidth}, torch::kDouble);  // shared queries
  const auto kv = torch::randn({2, 7, kWidth}, torch::kDouble);
  const auto out = blk->forward_cross(le, kv);
  ASSERT_EQ(out.sizes(), (std::vector<int64_t>{2, 5, kWidth}));
  for (int64_t r = 0; r < 2; ++r)
    EXPECT_TRUE(torch::allclose(out[r], ref_block(*blk, le[0], kv[r], torch::Tensor()), 1e-10, 1e-10)) << r;
}

TEST(Attention, FirstTokenPathEqualsRowZeroOfSelfAttention) {
  // forward_first computes the ray token's row alone (rendering's last coarse layer); the mask's
  // row 0 blocks nothing, so it must equal row 0 of the full masked self-attention, probe included.
  torch::manual_seed(3);
  TransformerBlock blk(kWidth, kHeads, kFF);
  blk->to(torch::kDouble);
  const int64_t b = 4, s = 9;
  const auto x = torch::randn({b, s + 1, kWidth}, torch::kDouble);
  RayQueryProbe full_probe, first_probe;
  const auto full = blk->forward_self(x, ray_attention_mask(s, torch::kDouble), &full_probe);
  const auto first = blk->forward_first(x, &first_probe);
  ASSERT_EQ(first.sizes(), (std::vector<int64_t>{b, 1, kWidth}));
  EXPECT_LT((first.select(1, 0) - full.select(1, 0)).abs().max().item<double>(), 1e-12);
  EXPECT_LT((ray_token_attention(first_probe) - ray_token_attention(full_probe)).abs().max().item<double>(), 1e-12);
  // And it is not row 1 (a test that could not tell the rows apart would pass either way).
  EXPECT_GT((first.select(1, 0) - full.select(1, 1)).abs().max().item<double>(), 1e-3);
}

TEST(Attention, FartherVolumesNeverReachNearerOnes) {
  // One layer: the mask is per layer. From the second layer on, information from farther
  // volumes does reach nearer ones through the ray token (row 0 sees all, column 0 is visible
  // to every volume): that is the release's design, not a leak in the mask.
  torch::manual_seed(3);
  ABTransformer ab(kWidth, kHeads, kFF, 1);
  const int64_t s = 10, changed = 6;  // token index 6 = volume 6
  const auto x = torch::randn({2, s + 1, kWidth});
  auto x2 = x.clone();
  x2.select(1, changed).add_(torch::randn({2, kWidth}));
  const auto mask = ray_attention_mask(s);
  auto diff = [](const torch::Tensor& a, const torch::Tensor& b, int64_t row) {
    return (a.select(1, row) - b.select(1, row)).abs().max().item<double>();
  };
  const auto y = ab->forward(x, mask), y2 = ab->forward(x2, mask);
  for (int64_t i = 1; i < changed; ++i) EXPECT_EQ(diff(y, y2, i), 0.0) << "nearer volume " << i;
  for (int64_t i = changed; i <= s; ++i) EXPECT_GT(diff(y, y2, i), 1e-4) << "volume " << i;
  EXPECT_GT(diff(y, y2, 0), 1e-4) << "the ray token sees every volume";
  // Bidirectional ablation: nearer volumes do see it.
  const auto z = ab->forward(x, torch::Tensor()), z2 = ab->forward(x2, torch::Tensor());
  for (int64_t i = 1; i < changed; ++i) EXPECT_GT(diff(z, z2, i), 1e-4) << i;
}

TEST(Attention, InitialisationFollowsPyTorchDefaults) {
  torch::manual_seed(5);
  TransformerBlock blk(kWidth, kHeads, kFF);
  const auto& a = *blk->attn;
  const double xavier = std::sqrt(6.0 / (kWidth + 3 * kWidth));  // fan_in 192, fan_out 576
  EXPECT_LE(a.in_proj_weight.abs().max().item<double>(), xavier);
  // Uniform(-b, b) has std b/sqrt(3); 110k samples pin it to well under 2%.
  EXPECT_NEAR(a.in_proj_weight.std().item<double>(), xavier / std::sqrt(3.0), 0.02 * xavier);
  EXPECT_EQ(a.in_proj_bias.abs().max().item<double>(), 0.0);
  EXPECT_EQ(a.out_proj->bias.abs().max().item<double>(), 0.0);
  const double lin = 1.0 / std::sqrt(static_cast<double>(kWidth));
  EXPECT_LE(a.out_proj->weight.abs().max().item<double>(), lin);
  EXPECT_NEAR(a.out_proj->weight.std().item<double>(), lin / std::sqrt(3.0), 0.03 * lin);
  EXPECT_LE(blk->ff_out->bias.abs().max().item<double>(), 1.0 / std::sqrt(static_cast<double>(kFF)));
  EXPECT_GT(blk->ff_out->bias.abs().max().item<double>(), 0.5 / std::sqrt(static_cast<double>(kFF)));
  EXPECT_TRUE(torch::equal(blk->norm1->weight, torch::ones({kWidth})));
  EXPECT_TRUE(torch::equal(blk->norm2->bias, torch::zeros({kWidth})));
  int64_t n = 0;
  for (const auto& p : blk->parameters()) n += p.numel();
  EXPECT_EQ(n, 370944);  // docs/MODEL.md, section 11
}

// compute.attention = "plain" is the reference that `bench --compare` divides by: on the CPU it
// must compute what "fused" (the packed BLAS kernel) computes, values and gradients, with the ray
// mask and without, in self- and cross-attention.
TEST(Attention, PlainEqualsFusedOnTheCpu) {
  torch::manual_seed(21);
  TransformerBlock blk(16, 2, 32);
  blk->to(torch::kDouble);
  const auto mask = ray_attention_mask(8).to(torch::kDouble);
  for (const bool masked : {true, false}) {
    std::vector<torch::Tensor> outs, grads;
    for (const AttentionKernel k : {AttentionKernel::Plain, AttentionKernel::Fused}) {
      blk->attn->set_kernel(k);
      torch::manual_seed(22);
      const auto x = torch::randn({3, 9, 16}, torch::kDouble).requires_grad_(true);
      const auto le = torch::randn({1, 4, 16}, torch::kDouble).requires_grad_(true);
      const auto self = blk->forward_self(x, masked ? mask : torch::Tensor());
      const auto cross = blk->forward_cross(le, self);
      const auto loss = (self * self).sum() + cross.sin().sum();
      const auto g = torch::autograd::grad({loss}, {x, le});
      outs.push_back(torch::cat({self.reshape({-1}), cross.reshape({-1})}).detach());
      grads.push_back(torch::cat({g[0].reshape({-1}), g[1].reshape({-1})}));
    }
    EXPECT_LT((outs[0] - outs[1]).abs().max().item<double>(), 1e-10) << "masked " << masked;
    EXPECT_LT((grads[0] - grads[1]).abs().max().item<double>(), 1e-9) << "masked " << masked;
    EXPECT_GT(grads[0].abs().max().item<double>(), 1e-3);  // not a comparison of zeros
  }
}

// The ray token's attention row (what the resampler, depth and the attention's losses read), with
// the probe keeping the graph: the fused CPU kernel returns the row itself, the plain path its
// query and keys; the same row and the same gradients of the block's input and parameters, from
// the full self-attention and from the ray token's row alone (forward_first).
TEST(Attention, RayTokenRowPlainEqualsFusedWithGradients) {
  torch::manual_seed(41);
  TransformerBlock blk(16, 2, 32);
  blk->to(torch::kDouble);
  const auto mask = ray_attention_mask(8).to(torch::kDouble);
  for (const bool first_only : {false, true}) {
    std::vector<torch::Tensor> rows, grads;
    for (const AttentionKernel k : {AttentionKernel::Plain, AttentionKernel::Fused}) {
      blk->attn->set_kernel(k);
      torch::manual_seed(42);
      const auto x = torch::randn({3, 9, 16}, torch::kDouble).requires_grad_(true);
      const auto w = torch::randn({3, 8}, torch::kDouble);
      RayQueryProbe probe;
      probe.keep_graph = true;
      if (first_only) {
        blk->forward_first(x, &probe);
      } else {
        blk->forward_self(x, mask, &probe);
      }
      const auto row = ray_token_attention(probe);  // (B, L - 1)
      std::vector<torch::Tensor> wrt{x, blk->attn->in_proj_weight, blk->attn->in_proj_bias};
      std::vector<torch::Tensor> flat;
      for (const auto& g : torch::autograd::grad({(row * w).sum()}, wrt)) flat.push_back(g.reshape({-1}));
      rows.push_back(row.detach());
      grads.push_back(torch::cat(flat));
    }
    ASSERT_EQ(rows[0].sizes(), (std::vector<int64_t>{3, 8}));
    EXPECT_LT((rows[0] - rows[1]).abs().max().item<double>(), 1e-12) << "first only " << first_only;
    EXPECT_LT((grads[0] - grads[1]).abs().max().item<double>(), 1e-10) << "first only " << first_only;
    EXPECT_GT(grads[0].abs().max().item<double>(), 1e-3);  // not a comparison of zeros
  }
}

// In float32 the fused path also runs each block's tail as one node (kernels/block_tail.h): the
// block's output and the gradients of its inputs and of every parameter equal the plain path's,
// with the ray mask and without, in self- and cross-attention (the LE's shared queries included).
TEST(Attention, FusedTailEqualsPlainInFloat32OnTheCpu) {
  torch::manual_seed(31);
  TransformerBlock blk(32, 2, 64);
  const auto mask = ray_attention_mask(16);
  for (const bool masked : {true, false}) {
    std::vector<torch::Tensor> outs, grads;
    for (const AttentionKernel k : {AttentionKernel::Plain, AttentionKernel::Fused}) {
      blk->attn->set_kernel(k);
      blk->zero_grad();
      torch::manual_seed(32);
      const auto x = torch::randn({5, 17, 32}).requires_grad_(true);
      const auto le = torch::randn({1, 8, 32}).requires_grad_(true);
      const auto self = blk->forward_self(x, masked ? mask : torch::Tensor());
      const auto cross = blk->forward_cross(le, self);
      const auto loss = (self * self).sum() + cross.sin().sum();
      std::vector<torch::Tensor> wrt{x, le};
      for (const auto& p : blk->parameters()) wrt.push_back(p);
      std::vector<torch::Tensor> flat;
      for (const auto& g : torch::autograd::grad({loss}, wrt)) flat.push_back(g.reshape({-1}));
      outs.push_back(torch::cat({self.reshape({-1}), cross.reshape({-1})}).detach());
      grads.push_back(torch::cat(flat));
    }
    EXPECT_LT((outs[0] - outs[1]).abs().max().item<double>(), 1e-4) << "masked " << masked;
    const double scale = std::max(1.0, grads[0].abs().max().item<double>());
    EXPECT_LT((grads[0] - grads[1]).abs().max().item<double>(), 1e-4 * scale) << "masked " << masked;
    EXPECT_GT(grads[0].abs().max().item<double>(), 1e-3);  // not a comparison of zeros
  }
}

}  // namespace
}  // namespace ablenerf
