// Stage 5: blur-pool, inverse-CDF sampling against hand-computed values, concentration at the
// attention peak, and the ray-token attention row recomputed from one extra query.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <functional>
#include <limits>
#include <string>

#include "kernels/sample_pdf_cpu.h"
#include "model/ab_transformer.h"
#include "model/resampler.h"

namespace ablenerf {
namespace {

TEST(Resampler, BlurPoolByHand) {
  // pad -> [0,0,1,0,0,0]; pair max -> [0,1,1,0,0]; pair mean -> [.5,1,.5,0]; + 0.01.
  const auto w = torch::tensor({0.0, 1.0, 0.0, 0.0}).view({1, 4});
  const auto b = blur_weights(w, 0.01);
  EXPECT_TRUE(torch::allclose(b, torch::tensor({0.51, 1.01, 0.51, 0.01}).view({1, 4})));
}

TEST(Resampler, InverseCdfByHand) {
  // Bins [0,1,2,3,4], weights [1,0,3,0] -> pdf [.25,0,.75,0], cdf [0,.25,.25,1,1].
  // u = k (1-eps)/4: 0 -> 0; ~.25 -> end of bin 0 (t ~ 1); .5 -> 2 + (.5-.25)/.75 = 2 1/3;
  // .75 -> 2 2/3; ~1 -> 3. The empty bin [1,2] and the last bin [3,4] receive nothing.
  const auto bins = torch::tensor({0.0f, 1.0f, 2.0f, 3.0f, 4.0f}).view({1, 5});
  const auto w = torch::tensor({1.0f, 0.0f, 3.0f, 0.0f}).view({1, 4});
  const auto t = sample_pdf(bins, w, 5)[0];
  const std::vector<double> expected{0.0, 1.0, 2.0 + 1.0 / 3.0, 2.0 + 2.0 / 3.0, 3.0};
  for (int i = 0; i < 5; ++i) EXPECT_NEAR(t[i].item<double>(), expected[i], 2e-6) << i;
}

TEST(Resampler, ConcentratesWhereWeightsPeakAndStaysSortedInRange) {
  const int64_t s = 96;
  const auto t = coarse_fence_posts(2, 2.0, 6.0, s, torch::kFloat);
  const auto centre = torch::arange(s, torch::kFloat);
  // Ray 0 peaks at interval 60 (t ~ 4.5), ray 1 at interval 10 (t ~ 2.44).
  const auto w = torch::stack({torch::exp(-0.5 * (centre - 60).pow(2)), torch::exp(-0.5 * (centre - 10).pow(2))}) * 0.9;
  const auto f = resample_fence_posts(t, w, 0.01);
  ASSERT_EQ(f.sizes(), (std::vector<int64_t>{2, s + 1}));
  EXPECT_TRUE(torch::all(f.slice(1, 1) >= f.slice(1, 0, s)).item<bool>());
  EXPECT_NEAR(f.min().item<double>(), 2.0, 1e-6);
  EXPECT_LE(f.max().item<double>(), 6.0);
  EXPECT_NEAR(f[0][s].item<double>(), 6.0, 1e-4);
  const double width = 4.0 / s;
  for (int r = 0; r < 2; ++r) {
    const double peak = 2.0 + width * ((r == 0 ? 60 : 10) + 0.5);
    const auto near_peak = ((f[r] - peak).abs() < 4 * width).sum().item<int64_t>();
    EXPECT_GT(near_peak, 0.7 * (s + 1)) << r;  // uniform spacing would put ~8 there
  }
}

TEST(Resampler, CoarseJitterMovesEachPostBetweenTheGridMidPoints) {
  // Grid 2,3,4,5,6 (4 intervals); mid-points 2.5..5.5. Post k lies in [lower_k, upper_k] =
  // [2,2.5], [2.5,3.5], [3.5,4.5], [4.5,5.5], [5.5,6] at lower + u (upper - lower).
  const auto u = torch::stack({torch::zeros({5}), torch::full({5}, 0.5f), torch::full({5}, 0.999f)});
  const auto t = coarse_fence_posts(3, 2.0, 6.0, 4, torch::kFloat, u);
  const std::vector<std::vector<double>> expected{
      {2.0, 2.5, 3.5, 4.5, 5.5}, {2.25, 3.0, 4.0, 5.0, 5.75}, {2.4995, 3.499, 4.499, 5.499, 5.9995}};
  for (int r = 0; r < 3; ++r) {
    for (int k = 0; k < 5; ++k) EXPECT_NEAR(t[r][k].item<double>(), expected[r][k], 1e-5) << r << " " << k;
  }
  EXPECT_TRUE(
      torch::equal(coarse_fence_posts(3, 2.0, 6.0, 4, torch::kFloat), torch::linspace(2.0, 6.0, 5).expand({3, 5})));
  EXPECT_THROW(coarse_fence_posts(3, 2.0, 6.0, 4, torch::kFloat, torch::zeros({3, 4})), c10::Error);
}

TEST(Resampler, StratifiedInverseCdfByHand) {
  // The setup of InverseCdfByHand (cdf 0,.25,.25,1,1 over bins 0..4) with 4 draws,
  // u_k = (k + j (1 - eps)) / 4. j = 0: u = 0,.25,.5,.75 -> 0, 2 (u = .25 starts bin 2), 2 1/3, 2 2/3.
  // j = 1/2: u = .125,.375,.625,.875 -> .5, 2 + .125/.75, 2 + .375/.75, 2 + .625/.75.
  const auto bins = torch::tensor({0.0f, 1.0f, 2.0f, 3.0f, 4.0f}).view({1, 5}).expand({2, 5});
  const auto w = torch::tensor({1.0f, 0.0f, 3.0f, 0.0f}).view({1, 4}).expand({2, 4});
  const auto j = torch::stack({torch::zeros({4}), torch::full({4}, 0.5f)});
  const auto t = sample_pdf(bins, w, 4, j);
  const std::vector<std::vector<double>> expected{{0.0, 2.0, 2.0 + 1.0 / 3.0, 2.0 + 2.0 / 3.0},
                                                  {0.5, 2.0 + 1.0 / 6.0, 2.5, 2.0 + 5.0 / 6.0}};
  for (int r = 0; r < 2; ++r) {
    for (int k = 0; k < 4; ++k) EXPECT_NEAR(t[r][k].item<double>(), expected[r][k], 2e-6) << r << " " << k;
  }
}

TEST(Resampler, JitteredPostsStaySortedAndInRange) {
  const int64_t s = 32;
  auto g = at::detail::createCPUGenerator(7);
  const auto t = coarse_fence_posts(3, 2.0, 6.0, s, torch::kFloat, uniform_like({3, s + 1}, &g, torch::kFloat));
  EXPECT_TRUE(torch::all(t.slice(1, 1) >= t.slice(1, 0, s)).item<bool>());
  // Each post stays between its neighbours' mid-points of the regular grid.
  const auto grid = coarse_fence_posts(3, 2.0, 6.0, s, torch::kFloat);
  EXPECT_LE((t - grid).abs().max().item<double>(), 0.5 * 4.0 / s + 1e-6);
  const auto w = torch::rand({3, s}, g);
  const auto f = resample_fence_posts(t, w, 0.01, uniform_like({3, s + 1}, &g, torch::kFloat));
  EXPECT_TRUE(torch::all(f.slice(1, 1) >= f.slice(1, 0, s)).item<bool>());
  EXPECT_GE(f.min().item<double>(), 2.0);
  EXPECT_LE(f.max().item<double>(), 6.0);
}

// The fused loop (kernels/sample_pdf_cpu.h) on the two hand-computed cases above.
TEST(Resampler, FusedInverseCdfByHand) {
  const auto bins = torch::tensor({0.0f, 1.0f, 2.0f, 3.0f, 4.0f}).view({1, 5});
  const auto w = torch::tensor({1.0f, 0.0f, 3.0f, 0.0f}).view({1, 4});
  const auto t = sample_pdf(bins, w, 5, {}, /*fused=*/true)[0];
  const std::vector<double> expected{0.0, 1.0, 2.0 + 1.0 / 3.0, 2.0 + 2.0 / 3.0, 3.0};
  for (int i = 0; i < 5; ++i) EXPECT_NEAR(t[i].item<double>(), expected[i], 2e-6) << i;
  const auto bins2 = bins.expand({2, 5}).contiguous(), w2 = w.expand({2, 4}).contiguous();
  const auto j = torch::stack({torch::zeros({4}), torch::full({4}, 0.5f)});
  ASSERT_TRUE(sample_pdf_cpu_available(bins2, w2, j));
  const auto s = sample_pdf(bins2, w2, 4, j, /*fused=*/true);
  const std::vector<std::vector<double>> strat{{0.0, 2.0, 2.0 + 1.0 / 3.0, 2.0 + 2.0 / 3.0},
                                               {0.5, 2.0 + 1.0 / 6.0, 2.5, 2.0 + 5.0 / 6.0}};
  for (int r = 0; r < 2; ++r)
    for (int k = 0; k < 4; ++k) EXPECT_NEAR(s[r][k].item<double>(), strat[r][k], 2e-6) << r << " " << k;
}

// The fused loop against the LibTorch reference over the presets' shapes and odd ones: one bin, a
// single draw, more draws than bins; fixed and stratified u; rows of random weights, one of zeros
// and one summing below the padding floor (both padded towards uniform), one peaked. Every bin
// keeps some weight or the whole row is padded, so the inverse CDF is continuous and float32
// rounding moves a value by little.
TEST(Resampler, FusedInverseCdfMatchesTheReference) {
  auto g = at::detail::createCPUGenerator(31);
  int checked = 0;
  for (const int64_t s : {1, 2, 16, 32, 33}) {
    for (const int64_t count : {int64_t{1}, s + 1, 2 * s + 3}) {
      for (const bool jittered : {false, true}) {
        const int64_t b = 5;
        auto w = torch::rand({b, s}, g) + 0.01;
        w[1].zero_();
        w[2].fill_(1e-7);
        w[3] = torch::exp(-0.5 * (torch::arange(s, torch::kFloat) - s / 3.0).pow(2)) + 1e-3;
        const auto bins = std::get<0>(torch::sort(torch::rand({b, s + 1}, g) * 4.0 + 2.0, 1)).contiguous();
        const auto jitter = jittered ? torch::rand({b, count}, g) : torch::Tensor();
        const auto want = sample_pdf(bins, w, count, jitter, /*fused=*/false);
        ASSERT_TRUE(sample_pdf_cpu_available(bins, w, jitter));
        const auto got = sample_pdf(bins, w, count, jitter, /*fused=*/true);
        ASSERT_EQ(got.sizes(), want.sizes());
        EXPECT_LT((got - want).abs().max().item<double>(), 2e-5) << s << " " << count << " " << jittered;
        if (count > 1) EXPECT_TRUE(torch::all(got.slice(1, 1) >= got.slice(1, 0, count - 1)).item<bool>());
        EXPECT_TRUE(torch::all(got >= bins.select(1, 0).unsqueeze(1)).item<bool>());
        EXPECT_TRUE(torch::all(got <= bins.select(1, s).unsqueeze(1)).item<bool>());
        ++checked;
      }
    }
  }
  EXPECT_EQ(checked, 30);
}

// What the fused loop does not take falls back to the reference; bad shapes are refused naming it.
TEST(Resampler, FusedInverseCdfRefusals) {
  const auto bins = torch::linspace(0, 1, 5).view({1, 5}), w = torch::ones({1, 4});
  EXPECT_FALSE(sample_pdf_cpu_available(bins.to(torch::kDouble), w.to(torch::kDouble), {}));
  EXPECT_FALSE(sample_pdf_cpu_available(bins.expand({2, 5}), w.expand({2, 4}), {}));
  EXPECT_FALSE(sample_pdf_cpu_available(bins, w.clone().requires_grad_(), {}));
  EXPECT_FALSE(sample_pdf_cpu_available(bins.slice(1, 0, 4), w, {}));
  // The non-contiguous case still gives the reference's answer through sample_pdf.
  EXPECT_TRUE(torch::allclose(sample_pdf(bins.expand({2, 5}), w.expand({2, 4}), 3, {}, true),
                              sample_pdf(bins.expand({2, 5}), w.expand({2, 4}), 3, {}, false)));
  const SamplePdfConstants k{1e-5, 1e-5, 1e-7};
  const auto expect_refused = [&](const std::function<void()>& f, const std::string& what) {
    try {
      f();
      ADD_FAILURE() << "not refused: " << what;
    } catch (const c10::Error& e) {
      const std::string m = e.what_without_backtrace();
      EXPECT_NE(m.find("sample_pdf_cpu"), std::string::npos) << m;
      EXPECT_NE(m.find(what), std::string::npos) << m;
    }
  };
  expect_refused([&] { sample_pdf_cpu(bins, torch::ones({1, 5}), 3, {}, k); }, "bins");
  expect_refused([&] { sample_pdf_cpu(bins, w, 0, {}, k); }, "count");
  expect_refused([&] { sample_pdf_cpu(bins, w, 3, torch::rand({1, 2}), k); }, "jitter");
  expect_refused([&] { sample_pdf_cpu(bins, torch::ones({1, 4, 1}), 3, {}, k); }, "weights");
}

TEST(Resampler, RayTokenRowFromOneQueryMatchesFullAttention) {
  torch::manual_seed(11);
  const int64_t e = 48, heads = 3, s = 12, b = 2, dh = e / heads;
  ABTransformer ab(e, heads, 2 * e, 2);
  const auto x = torch::randn({b, s + 1, e});
  RayQueryProbe probe;
  const auto mask = ray_attention_mask(s);
  ab->forward(x, mask, &probe);
  const auto w = ray_token_attention(probe);
  ASSERT_EQ(w.sizes(), (std::vector<int64_t>{b, s}));
  EXPECT_FALSE(w.requires_grad());
  // Reference: the last block's input, its projections and the full masked attention matrix.
  const auto h = ab->block(0)->forward_self(x, mask);
  const auto& a = *ab->block(1)->attn;
  const auto q = (h.matmul(a.in_proj_weight.slice(0, 0, e).t()) + a.in_proj_bias.slice(0, 0, e))
                     .view({b, s + 1, heads, dh})
                     .transpose(1, 2);
  const auto k = (h.matmul(a.in_proj_weight.slice(0, e, 2 * e).t()) + a.in_proj_bias.slice(0, e, 2 * e))
                     .view({b, s + 1, heads, dh})
                     .transpose(1, 2);
  const auto full = torch::softmax(q.matmul(k.transpose(-2, -1)) / std::sqrt(double(dh)) + mask, -1);  // (B,H,L,L)
  const auto expected = full.select(2, 0).mean(1).slice(1, 1);
  EXPECT_TRUE(torch::allclose(w, expected, 1e-5, 1e-6));
  EXPECT_LT(w.sum(1).max().item<double>(), 1.0);  // column 0 dropped, not renormalised
}

}  // namespace
}  // namespace ablenerf
