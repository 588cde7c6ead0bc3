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

// Coarse pixels (train.coarse_pixel_*): a coarse pixel's ray is the ray of the camera reduced f times
// (focal length and principal point divided by f) through that pixel, its radius that camera's, its
// target the mean of its f x f block; full pixels drawn beside them are unchanged.
TEST(RaySampler, CoarsePixelsAreTheReducedCamerasPixels) {
  const int n = 2, h = 7, w = 9, f = 2;  // odd sizes: the last row and column belong to no block
  Split s = make_split(n, h, w);
  Intrinsics k = intr(h, w);
  k.cx = 4.3, k.cy = 3.1;
  Intrinsics reduced = k;
  reduced.width = w / f, reduced.height = h / f;
  reduced.fx = k.fx / f, reduced.fy = k.fy / f, reduced.cx = k.cx / f, reduced.cy = k.cy / f;
  RaySampler sampler(s, k, torch::kCPU, 5, std::nullopt, f);
  ASSERT_EQ(sampler.coarse_pixels(), n * (h / f) * (w / f));
  const int64_t coarse = 30, total = 40;
  const auto idx = sampler.draw(total, coarse);
  const RayBatch b = sampler.gather(idx);
  for (int64_t r = 0; r < total; ++r) {
    const int64_t flat = idx[r].item<int64_t>();
    if (r >= coarse) {
      ASSERT_LT(flat, sampler.pixels());
      const int64_t img = flat / (h * w), pix = flat % (h * w);
      const Rays full = rays_for_image(s.c2w[img], k);
      EXPECT_TRUE(torch::allclose(b.rays.directions[r], full.directions[pix]));
      EXPECT_TRUE(torch::allclose(b.rays.radii[r], full.radii[pix]));
      EXPECT_TRUE(torch::equal(b.target[r], s.images[img].reshape({-1, 3})[pix]));
      continue;
    }
    ASSERT_GE(flat, sampler.pixels());
    const int64_t c = flat - sampler.pixels(), per = reduced.width * reduced.height;
    const int64_t img = c / per, row = (c % per) / reduced.width, col = (c % per) % reduced.width;
    ASSERT_LT(img, n);
    EXPECT_EQ(b.photo[r].item<int64_t>(), img);
    const Rays ref = rays_for_image(s.c2w[img], reduced);
    const int64_t at = row * reduced.width + col;
    EXPECT_TRUE(torch::allclose(b.rays.directions[r], ref.directions[at], 1e-6, 1e-6));
    EXPECT_TRUE(torch::allclose(b.rays.origins[r], ref.origins[at]));
    EXPECT_TRUE(torch::allclose(b.rays.radii[r], ref.radii[at], 1e-6, 1e-7));
    double mean[3] = {0, 0, 0};
    for (int dy = 0; dy < f; ++dy)
      for (int dx = 0; dx < f; ++dx)
        for (int ch = 0; ch < 3; ++ch)
          mean[ch] += s.images[img][row * f + dy][col * f + dx][ch].item<double>() / (f * f);
    for (int ch = 0; ch < 3; ++ch) EXPECT_NEAR(b.target[r][ch].item<double>(), mean[ch], 1e-6);
  }
}

// With lenses (a phone's radial-tangential camera shared by two images, a fisheye for the third),
// the sampler's looked-up rays are rays_for_pixels' through each image's own camera, full pixels
// and coarse ones (the block's centre through the camera reduced f times, its cone f times wider).
TEST(RaySampler, LensRaysAreEachImagesOwnCamerasRays) {
  const int n = 3, h = 9, w = 11, f = 3;
  Split s = make_split(n, h, w);
  Intrinsics phone = intr(h, w), fisheye = intr(h, w);
  phone.model = LensModel::RadialTangential, phone.dist = {-0.12, 0.03, 0.0, 0.0, 0.001, -0.002};
  phone.cx = 5.2, phone.cy = 4.7;
  fisheye.model = LensModel::Fisheye, fisheye.dist = {0.05, -0.01, 0.003, -0.0005, 0.0, 0.0};
  s.cameras = {phone, fisheye, phone};
  RaySampler sampler(s, phone, torch::kCPU, 3, std::nullopt, f);
  const int64_t coarse = 40, total = 200;
  const auto idx = sampler.draw(total, coarse);
  const RayBatch b = sampler.gather(idx);
  for (int64_t r = 0; r < total; ++r) {
    const int64_t flat = idx[r].item<int64_t>();
    const bool is_coarse = flat >= sampler.pixels();
    Intrinsics k;
    int64_t img = 0, row = 0, col = 0;
    if (is_coarse) {
      const int64_t c = flat - sampler.pixels(), per = (h / f) * (w / f);
      img = c / per, row = (c % per) / (w / f), col = (c % per) % (w / f);
      k = s.cameras[static_cast<size_t>(img)];
      k.fx /= f, k.fy /= f, k.cx /= f, k.cy /= f;
    } else {
      img = flat / (h * w), row = flat % (h * w) / w, col = flat % w;
      k = s.cameras[static_cast<size_t>(img)];
    }
    const Rays want =
        rays_for_pixels(s.c2w[img].unsqueeze(0), torch::tensor({col}), torch::tensor({row}), CameraTable::of({k}));
    EXPECT_TRUE(torch::allclose(b.rays.directions[r], want.directions[0], 1e-6, 1e-6)) << r;
    EXPECT_TRUE(torch::equal(b.rays.origins[r], want.origins[0])) << r;
    EXPECT_TRUE(torch::allclose(b.rays.radii[r], want.radii[0], 1e-6, 1e-7)) << r;
    // Not the pinhole's ray: the lens is undone.
    if (!is_coarse && std::abs(col - w / 2) > 2) {
      Intrinsics pin = k;
      pin.model = LensModel::Pinhole;
      const Rays flat_ray =
          rays_for_pixels(s.c2w[img].unsqueeze(0), torch::tensor({col}), torch::tensor({row}), CameraTable::of({pin}));
      EXPECT_GT((flat_ray.directions[0] - b.rays.directions[r]).abs().max().item<double>(), 1e-3) << r;
    }
  }
}

// Without coarse draws the stream is the one a sampler without coarse pixels draws; with a mask,
// coarse pixels come only from blocks whose every pixel is kept, and all of those are drawn.
TEST(RaySampler, CoarseDrawsKeepTheStreamAndTheMask) {
  const int n = 2, h = 8, w = 10, f = 2;
  Split s = make_split(n, h, w);
  const Intrinsics k = intr(h, w);
  {
    RaySampler plain(s, k, torch::kCPU, 11), with(s, k, torch::kCPU, 11, std::nullopt, f);
    EXPECT_TRUE(torch::equal(plain.draw(64), with.draw(64, 0)));
  }
  auto g = at::detail::createCPUGenerator(4);
  s.mask = torch::rand({n, h, w}, g).lt(0.8);
  const auto blocks =
      s.mask.reshape({n, h / f, f, w / f, f}).permute({0, 1, 3, 2, 4}).reshape({n, h / f, w / f, f * f});
  const auto whole = blocks.all(-1).reshape({-1});
  ASSERT_GT(whole.sum().item<int64_t>(), 3);
  ASSERT_LT(whole.sum().item<int64_t>(), whole.numel());
  RaySampler sampler(s, k, torch::kCPU, 12, ErrorMapOptions{4, 0.25}, f);
  const int64_t draws = 200 * whole.numel();
  const auto idx = sampler.draw(draws, draws);
  ASSERT_TRUE(idx.ge(sampler.pixels()).all().item<bool>());
  const auto counts = torch::bincount(idx - sampler.pixels(), {}, whole.numel());
  EXPECT_EQ(counts.masked_select(whole.logical_not()).sum().item<int64_t>(), 0);
  EXPECT_GT(counts.masked_select(whole).min().item<int64_t>(), 0);
}

// A coarse pixel's error reaches the error map as the error of its block's first pixel.
TEST(RaySampler, CoarsePixelErrorsFeedTheTileOfTheirBlock) {
  const int n = 2, h = 8, w = 8, f = 2;
  Split s = make_split(n, h, w);
  const Intrinsics k = intr(h, w);
  const ErrorMapOptions options{4, 0.25};
  RaySampler sampler(s, k, torch::kCPU, 3, options, f);
  // Coarse pixel (image 1, row 3, column 2) of the 4x4 reduced images: its block starts at full pixel
  // (image 1, row 6, column 4).
  const int64_t coarse = sampler.pixels() + 1 * 16 + 3 * 4 + 2, first = 1 * 64 + 6 * 8 + 4;
  const auto errors = torch::tensor({9.0, 1.0, 4.0}, torch::kDouble);
  sampler.observe(torch::tensor({coarse, int64_t{3}, int64_t{70}}), errors);
  ErrorMap reference(n, h, w, options);
  reference.observe(torch::tensor({first, int64_t{3}, int64_t{70}}), errors);
  EXPECT_TRUE(torch::equal(sampler.map_state(), reference.state()));
}

TEST(RaySampler, CoarsePixelShareFallsLinearly) {
  EXPECT_EQ(coarse_pixel_rays(256, 0.5, 0.5, 0.0), 128);
  EXPECT_EQ(coarse_pixel_rays(256, 0.5, 0.5, 0.25), 64);
  EXPECT_EQ(coarse_pixel_rays(256, 0.5, 0.5, 0.5), 0);
  EXPECT_EQ(coarse_pixel_rays(256, 0.5, 0.5, 0.9), 0);
  EXPECT_EQ(coarse_pixel_rays(256, 1.0, 1.0, 0.0), 256);
  EXPECT_EQ(coarse_pixel_rays(256, 0.0, 0.5, 0.0), 0);
  EXPECT_EQ(coarse_pixel_rays(100, 0.75, 0.6, 0.3), 38);  // 0.75 x (1 - 0.5) x 100 = 37.5, rounded away from 0
}
