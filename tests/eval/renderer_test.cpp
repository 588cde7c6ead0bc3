// render_image against a direct model forward, chunking invariance, LE-noise consistency, and
// depth from attention on hand-computed cases.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <ATen/CPUGeneratorImpl.h>

#include "eval/camera_path.h"
#include "eval/renderer.h"
#include "eval_fixtures.h"

using namespace ablenerf;

namespace {

constexpr double kNear = 2.0, kFar = 6.0;
constexpr int kTinySide = 8;

Intrinsics tiny_intrinsics() {
  Intrinsics k;
  k.width = k.height = kTinySide;
  k.fx = k.fy = 10.0;
  k.cx = k.cy = kTinySide / 2.0;
  return k;
}

torch::Tensor test_pose() {
  return look_at(torch::tensor({3.0, -2.0, 1.5}, torch::kDouble), torch::zeros({3}, torch::kDouble),
                 torch::tensor({0.0, 0.0, 1.0}, torch::kDouble));
}

AbleNerf tiny_model() {
  torch::manual_seed(3);
  AbleNerf m(test::tiny_model_config().get<ModelConfig>());
  m->eval();
  return m;
}

}  // namespace

TEST(DepthFromAttention, HandComputedMeanAndArgmax) {
  // Row 0: weights sum to 1; mid-points 2.5, 4, 5.5 -> mean 0.1*2.5 + 0.6*4 + 0.3*5.5 = 4.3.
  // Row 1: weights sum to 0.4 (the ray token keeps the rest); mid-points 3, 4.25, 5.25
  //        -> mean (0.1*3 + 0.05*4.25 + 0.25*5.25) / 0.4 = 4.5625; peak at the last volume.
  const auto w = torch::tensor({{0.1, 0.6, 0.3}, {0.1, 0.05, 0.25}}, torch::kDouble);
  const auto t = torch::tensor({{2.0, 3.0, 5.0, 6.0}, {2.0, 4.0, 4.5, 6.0}}, torch::kDouble);
  const auto d = depth_from_attention(w, t);
  EXPECT_NEAR(d.mean[0].item<double>(), 4.3, 1e-12);
  EXPECT_NEAR(d.mean[1].item<double>(), 4.5625, 1e-12);
  EXPECT_DOUBLE_EQ(d.argmax[0].item<double>(), 4.0);
  EXPECT_DOUBLE_EQ(d.argmax[1].item<double>(), 5.25);
}

TEST(DepthFromAttention, HandComputedShareCrossingsAndTheFront) {
  // Where the normalised attention's cumulative sum reaches a share, linearly inside its interval.
  // Row 0: shares 0.1, 0.6, 0.3 (cumulative 0.1, 0.7, 1): one half is reached in [3, 5], (0.5 - 0.1)
  //        / 0.6 = 2/3 of the way: 3 + 2 * 2/3.
  // Row 1: shares 0.25, 0.125, 0.625 (of 0.4): reached in [4.5, 6], (0.5 - 0.375) / 0.625 = 0.2 of
  //        the way: 4.8.
  // Row 2: shares 0.8, 0.1, 0.1: reached in the first interval [2, 3], 0.5 / 0.8 of the way.
  const auto w = torch::tensor({{0.1, 0.6, 0.3}, {0.1, 0.05, 0.25}, {0.8, 0.1, 0.1}}, torch::kDouble);
  const auto t = torch::tensor({{2.0, 3.0, 5.0, 6.0}, {2.0, 4.0, 4.5, 6.0}, {2.0, 3.0, 5.0, 6.0}}, torch::kDouble);
  const auto half = depth_at_attention_share(w, t, 0.5);
  EXPECT_NEAR(half[0].item<double>(), 3.0 + 2.0 * 2.0 / 3.0, 1e-12);
  EXPECT_NEAR(half[1].item<double>(), 4.8, 1e-12);
  EXPECT_NEAR(half[2].item<double>(), 2.625, 1e-12);
  // The front (a share of 0.15): row 0 in [3, 5], (0.15 - 0.1) / 0.6 of the way; row 1 in [2, 4],
  // 0.15 / 0.25 of the way; row 2 in [2, 3], 0.15 / 0.8 of the way.
  ASSERT_DOUBLE_EQ(kAttentionFrontShare, 0.15);
  const auto d = depth_from_attention(w, t);
  EXPECT_NEAR(d.front[0].item<double>(), 3.0 + 2.0 * 0.05 / 0.6, 1e-12);
  EXPECT_NEAR(d.front[1].item<double>(), 2.0 + 2.0 * 0.6, 1e-12);
  EXPECT_NEAR(d.front[2].item<double>(), 2.0 + 0.15 / 0.8, 1e-12);
  // No attention on the volumes: finite, inside the fence-posts.
  const auto z = depth_from_attention(torch::zeros({1, 3}, torch::kDouble), t.slice(0, 0, 1));
  EXPECT_TRUE(std::isfinite(z.front[0].item<double>()));
  EXPECT_GE(z.front[0].item<double>(), 2.0);
  EXPECT_LE(z.front[0].item<double>(), 6.0);
}

TEST(DepthFromAttention, ArgmaxPicksThePeakAndMeanStaysInsideTheFenceposts) {
  // A sharp peak at volume 5 of 10 equal intervals on [2, 6]: argmax = its mid-point 2 + 0.4*5.5.
  auto w = torch::full({1, 10}, 0.01);
  w[0][5] = 0.9;
  const auto t = torch::linspace(2.0, 6.0, 11).unsqueeze(0);
  const auto d = depth_from_attention(w, t);
  EXPECT_NEAR(d.argmax[0].item<double>(), 2.0 + 0.4 * 5.5, 1e-6);
  EXPECT_GT(d.mean[0].item<double>(), 2.0);
  EXPECT_LT(d.mean[0].item<double>(), 6.0);
  // All attention on the ray token (zero over volumes) must not give NaN.
  const auto z = depth_from_attention(torch::zeros({1, 10}), t);
  EXPECT_TRUE(std::isfinite(z.mean[0].item<double>()));
}

TEST(RenderImage, EqualsDirectForwardOverEveryRay) {
  AbleNerf model = tiny_model();
  const Intrinsics k = tiny_intrinsics();
  const auto pose = test_pose();
  ForwardOptions fo;
  fo.branches = true;
  const RenderResult r = render_image(model, pose, k, kNear, kFar, 64, fo, torch::kCPU);
  ModelOutput ref;
  {
    torch::NoGradGuard ng;
    ref = model->forward(rays_for_image(pose, k), kNear, kFar, fo);
  }
  ASSERT_EQ(r.rgb.sizes(), (std::vector<int64_t>{kTinySide, kTinySide, 3}));
  ASSERT_EQ(r.depth_mean.sizes(), (std::vector<int64_t>{kTinySide, kTinySide}));
  EXPECT_TRUE(torch::allclose(r.rgb.view({-1, 3}), ref.rgb_fine, 0, 1e-6));
  const auto d = depth_from_attention(ref.fine_weights, ref.fine_t);
  EXPECT_TRUE(torch::allclose(r.depth_mean.view({-1}), d.mean, 0, 1e-5));
  EXPECT_TRUE(torch::allclose(r.depth_argmax.view({-1}), d.argmax, 0, 1e-5));
  EXPECT_TRUE(torch::allclose(r.depth_front.view({-1}), d.front, 0, 1e-5));
  EXPECT_TRUE(torch::allclose(r.ray_colour.view({-1, 3}), ref.ray_colour_fine, 0, 1e-6));
  EXPECT_TRUE(torch::allclose(r.le_colour.view({-1, 3}), ref.le_colour_fine, 0, 1e-6));
  // Depths lie inside [near, far].
  EXPECT_GE(r.depth_mean.min().item<double>(), kNear);
  EXPECT_LE(r.depth_mean.max().item<double>(), kFar);
  // Pixel (row 2, col 5) is ray 2*8+5 of rays_for_image (row-major layout).
  EXPECT_TRUE(torch::allclose(r.rgb[2][5], ref.rgb_fine[2 * kTinySide + 5], 0, 1e-6));
}

TEST(RenderImage, ChunkSizeDoesNotChangeTheImage) {
  AbleNerf model = tiny_model();
  const Intrinsics k = tiny_intrinsics();
  int64_t calls = 0, last_done = 0;
  const RenderResult a =
      render_image(model, test_pose(), k, kNear, kFar, 7, {}, torch::kCPU, [&](int64_t done, int64_t total) {
        ++calls;
        EXPECT_GT(done, last_done);
        EXPECT_EQ(total, kTinySide * kTinySide);
        last_done = done;
      });
  const RenderResult b = render_image(model, test_pose(), k, kNear, kFar, 64, {}, torch::kCPU);
  EXPECT_EQ(calls, (kTinySide * kTinySide + 6) / 7);  // one report per chunk: ceil(64 / 7) = 10
  EXPECT_EQ(last_done, kTinySide * kTinySide);
  EXPECT_TRUE(torch::allclose(a.rgb, b.rgb, 0, 1e-6));
  EXPECT_TRUE(torch::allclose(a.depth_mean, b.depth_mean, 0, 1e-5));
  // Batch size changes GEMM blocking, so values agree to float rounding, not bit for bit, and an
  // argmax may flip between volumes whose attention ties to rounding. Check instead that both
  // chunkings pick a volume whose attention equals the ray's maximum (from a direct forward).
  ModelOutput ref;
  {
    torch::NoGradGuard ng;
    ref = model->forward(rays_for_image(test_pose(), k), kNear, kFar);
  }
  const auto mid = 0.5 * (ref.fine_t.slice(1, 0, -1) + ref.fine_t.slice(1, 1));  // (B,S)
  const auto peak = std::get<0>(ref.fine_weights.max(1));
  for (const RenderResult* r : {&a, &b}) {
    const auto picked = (mid - r->depth_argmax.view({-1, 1})).abs().argmin(1, true);  // volume index
    const auto w_picked = ref.fine_weights.gather(1, picked).squeeze(1);
    EXPECT_LT((peak - w_picked).max().item<double>(), 1e-5);
  }
}

TEST(RenderImage, SeededLeNoiseIsTheSameForEveryChunkAndLeavesTheGeneratorAlone) {
  AbleNerf model = tiny_model();
  const Intrinsics k = tiny_intrinsics();
  torch::Generator gen = at::detail::createCPUGenerator(11);
  ForwardOptions noisy;
  noisy.le_noise = 2.0;
  noisy.generator = &gen;
  const RenderResult a = render_image(model, test_pose(), k, kNear, kFar, 7, noisy, torch::kCPU);
  const RenderResult b = render_image(model, test_pose(), k, kNear, kFar, 64, noisy, torch::kCPU);
  const RenderResult clean = render_image(model, test_pose(), k, kNear, kFar, 64, {}, torch::kCPU);
  EXPECT_TRUE(torch::allclose(a.rgb, b.rgb, 0, 1e-6));
  EXPECT_GT((a.rgb - clean.rgb).abs().max().item<double>(), 1e-4) << "the LE noise had no effect";
  // The caller's generator was not advanced: its next draw equals a fresh one's.
  torch::Generator fresh = at::detail::createCPUGenerator(11);
  EXPECT_TRUE(torch::equal(torch::randn({4}, gen), torch::randn({4}, fresh)));
}
