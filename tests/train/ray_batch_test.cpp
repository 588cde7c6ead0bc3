// Training batches: rays for random (image, pixel) pairs equal the rays of the whole image at those
// pixels, targets are the right pixels, and rank slices tile the global batch.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <optional>

#include "train/ray_batch.h"

using namespace ablenerf;

namespace {
Split make_split(int n, int h, int w) {
  Split s;
  s.name = "train";
  s.images = torch::rand({n, h, w, 3});
  std::vector<torch::Tensor> poses;
  for (int i = 0; i < n; ++i) {
    auto p = torch::eye(4).slice(0, 0, 3).clone();
    p[0][3] = static_cast<float>(i);  // distinct origins identify the image
    p[2][3] = 4.0f;
    poses.push_back(p);
  }
  s.c2w = torch::stack(poses);
  return s;
}
Intrinsics intr(int h, int w) {
  Intrinsics k;
  k.width = w;
  k.height = h;
  k.fx = k.fy = 3.0;
  k.cx = 0.5 * w;
  k.cy = 0.5 * h;
  return k;
}
}  // namespace

TEST(RaySampler, RaysAndTargetsMatchTheImages) {
  const int n = 3, h = 5, w = 7;
  Split s = make_split(n, h, w);
  const Intrinsics k = intr(h, w);
  RaySampler sampler(s, k, torch::kCPU, 1);
  auto idx = sampler.draw(50);
  RayBatch b = sampler.gather(idx);
  for (int64_t r = 0; r < 50; ++r) {
    const int64_t flat = idx[r].item<int64_t>();
    const int64_t img = flat / (h * w), pix = flat % (h * w);
    Rays full = rays_for_image(s.c2w[img], k);
    EXPECT_TRUE(torch::allclose(b.rays.directions[r], full.directions[pix]));
    EXPECT_TRUE(torch::allclose(b.rays.origins[r], full.origins[pix]));
    EXPECT_TRUE(torch::equal(b.target[r], s.images[img].reshape({-1, 3})[pix]));
  }
}

TEST(RaySampler, RankSlicesTileTheGlobalBatch) {
  Split s = make_split(2, 4, 4);
  const Intrinsics k = intr(4, 4);
  RaySampler one(s, k, torch::kCPU, 7), r0(s, k, torch::kCPU, 7), r1(s, k, torch::kCPU, 7), r2(s, k, torch::kCPU, 7);
  RayBatch all = one.next(10);
  RayBatch a = r0.next(10, 0, 3), b = r1.next(10, 1, 3), c = r2.next(10, 2, 3);
  EXPECT_EQ(a.size() + b.size() + c.size(), 10);
  EXPECT_TRUE(torch::equal(torch::cat({a.target, b.target, c.target}), all.target));
}

TEST(RaySampler, UniformOverPixelsAndRestorable) {
  Split s = make_split(2, 2, 2);  // 8 pixels
  RaySampler sampler(s, intr(2, 2), torch::kCPU, 3);
  auto idx = sampler.draw(80000);
  auto counts = torch::bincount(idx, {}, 8).to(torch::kDouble);
  // each count ~ Binomial(80000, 1/8): sd ~ 93.5; 6 sd bound
  EXPECT_LT((counts - 10000).abs().max().item<double>(), 600);
  auto state = sampler.rng_state();
  auto next1 = sampler.draw(5);
  sampler.set_rng_state(state);
  EXPECT_TRUE(torch::equal(sampler.draw(5), next1));
}

// With a mask, neither uniform nor error-guided draws ever land on a masked pixel, and uniform
// draws cover the kept pixels evenly.
TEST(RaySampler, MaskedPixelsAreNeverDrawn) {
  const int n = 2, h = 6, w = 9;
  Split s = make_split(n, h, w);
  auto g = at::detail::createCPUGenerator(3);
  s.mask = torch::rand({n, h, w}, g).lt(0.4);
  const int64_t kept = s.mask.sum().item<int64_t>();
  ASSERT_GT(kept, 10);
  const Intrinsics k = intr(h, w);
  const auto flat_keep = s.mask.reshape({-1});
  for (const bool guided : {false, true}) {
    SCOPED_TRACE(guided ? "error map" : "uniform");
    RaySampler sampler(s, k, torch::kCPU, 9,
                       guided ? std::optional<ErrorMapOptions>(ErrorMapOptions{4, 0.25}) : std::nullopt);
    const int64_t draws = 400 * kept;
    const auto idx = sampler.draw(draws);
    const auto counts = torch::bincount(idx, {}, n * h * w);
    EXPECT_EQ(counts.masked_select(flat_keep.logical_not()).sum().item<int64_t>(), 0);
    EXPECT_GT(counts.masked_select(flat_keep).min().item<int64_t>(), 0);
    if (!guided) {
      // 400 expected per kept pixel: chi-square with kept - 1 degrees of freedom, bounded by its
      // mean plus 5 standard deviations.
      const auto c = counts.masked_select(flat_keep).to(torch::kDouble);
      const double chi2 = ((c - 400).pow(2) / 400).sum().item<double>();
      EXPECT_LT(chi2, (kept - 1) + 5 * std::sqrt(2.0 * (kept - 1)));
    }
  }
}
