// Error-guided ray sampling: tile probabilities by hand, the blend of observed errors, draw
// frequencies against those probabilities (a chi-square bound), pixels uniform inside their tile
// and never outside the image, and a checkpointed state that continues the same draws.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <map>

#include "train/error_map.h"

using namespace ablenerf;

namespace {

// 2 images of 5 x 6 pixels in tiles of 4: per image a 4x4 tile (16 px), a 4x2 (8), a 1x4 (4), a
// 1x2 (2); 60 pixels, 8 tiles.
ErrorMap small_map(double share) { return ErrorMap(2, 5, 6, {4, share}); }

torch::Generator gen(uint64_t seed) { return at::detail::createCPUGenerator(seed); }

}  // namespace

TEST(ErrorMap, UniformBeforeAnyErrorIsSeen) {
  const auto map = small_map(0.25);
  ASSERT_EQ(map.tiles(), 8);
  const auto p = map.probabilities();
  const double areas[8] = {16, 8, 4, 2, 16, 8, 4, 2};
  for (int t = 0; t < 8; ++t) EXPECT_NEAR(p[t].item<double>(), areas[t] / 60.0, 1e-15) << t;
}

TEST(ErrorMap, TileOfAPixel) {
  const auto map = small_map(0.25);
  // image 0: (row 0, col 0) -> tile 0; (row 3, col 5) -> 1; (row 4, col 0) -> 2; (row 4, col 5) -> 3;
  // image 1, (row 4, col 4) -> 7.
  EXPECT_EQ(map.tile_of(0), 0);
  EXPECT_EQ(map.tile_of(3 * 6 + 5), 1);
  EXPECT_EQ(map.tile_of(4 * 6 + 0), 2);
  EXPECT_EQ(map.tile_of(4 * 6 + 5), 3);
  EXPECT_EQ(map.tile_of(30 + 4 * 6 + 4), 7);
}

TEST(ErrorMap, ObservedErrorsByHand) {
  auto map = small_map(0.25);
  // First batch: pixels in tiles 0 and 5 with errors 0.4 and 0.2 (mean 0.3 seeds every tile), then
  // each tile moves halfway: tile 0 -> 0.35, tile 5 -> 0.25. Second batch: tile 0 twice, 0.05 then
  // 0.15 -> 0.35 -> 0.2 -> 0.175.
  map.observe(torch::tensor({0L, 30L + 5L}), torch::tensor({0.4, 0.2}));
  map.observe(torch::tensor({7L, 6L}), torch::tensor({0.05f, 0.15f}));
  const auto st = map.state();
  ASSERT_EQ(st.size(0), 9);
  EXPECT_EQ(st[0].item<double>(), 1.0);
  const double e[8] = {0.175, 0.3, 0.3, 0.3, 0.3, 0.25, 0.3, 0.3};
  double sum = 0;
  for (int t = 0; t < 8; ++t) {
    EXPECT_NEAR(st[t + 1].item<double>(), e[t], 1e-7) << t;
    sum += e[t];
  }
  const double areas[8] = {16, 8, 4, 2, 16, 8, 4, 2};
  const auto p = map.probabilities();
  for (int t = 0; t < 8; ++t) EXPECT_NEAR(p[t].item<double>(), 0.25 * areas[t] / 60.0 + 0.75 * e[t] / sum, 1e-7) << t;
  EXPECT_NEAR(p.sum().item<double>(), 1.0, 1e-12);
}

TEST(ErrorMap, NonFiniteErrorsAreIgnoredAndAllZeroFallsBackToUniform) {
  auto map = small_map(0.0);
  map.observe(torch::tensor({0L, 1L}), torch::tensor({0.0, std::nan("")}));
  // Seeded with the mean of a batch holding a NaN: NaN everywhere would poison the map, so the
  // seed itself must come from finite values only.
  const auto p = map.probabilities();
  EXPECT_FALSE(torch::isnan(p).any().item<bool>());
  // Every error is zero: the share of error-guided draws has nothing to follow, uniform it is.
  const double areas[8] = {16, 8, 4, 2, 16, 8, 4, 2};
  for (int t = 0; t < 8; ++t) EXPECT_NEAR(p[t].item<double>(), areas[t] / 60.0, 1e-15) << t;
}

TEST(ErrorMap, DrawFrequenciesFollowTheProbabilities) {
  auto map = small_map(0.25);
  map.observe(torch::tensor({0L, 13L, 24L, 59L}), torch::tensor({0.9, 0.1, 0.02, 0.5}));
  const auto p = map.probabilities();
  auto g = gen(11);
  const int64_t n = 200000;
  const auto idx = map.draw(n, g);
  ASSERT_EQ(idx.scalar_type(), torch::kLong);
  std::vector<double> count(8, 0.0);
  std::map<int64_t, int64_t> per_pixel;
  for (int64_t i = 0; i < n; ++i) {
    const int64_t px = idx[i].item<int64_t>();
    ASSERT_GE(px, 0);
    ASSERT_LT(px, 60);
    count[static_cast<size_t>(map.tile_of(px))] += 1;
    per_pixel[px]++;
  }
  // Pearson's chi-square over 8 tiles (7 degrees of freedom): the 99.99th percentile is 29.9.
  double chi2 = 0;
  for (int t = 0; t < 8; ++t) {
    const double expect = p[t].item<double>() * static_cast<double>(n);
    chi2 += (count[static_cast<size_t>(t)] - expect) * (count[static_cast<size_t>(t)] - expect) / expect;
  }
  EXPECT_LT(chi2, 29.9);
  // Inside a tile every pixel is equally likely: tile 0 of image 0 is rows 0-3 x cols 0-3; the
  // 16 counts against their mean, chi-square with 15 degrees of freedom (99.99th pct 42.6).
  double mean = count[0] / 16.0, chi2_in = 0;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) {
      const double k = static_cast<double>(per_pixel[r * 6 + c]);
      chi2_in += (k - mean) * (k - mean) / mean;
    }
  EXPECT_LT(chi2_in, 42.6);
  // The edge tile 3 of image 0 is the single pixel row 4, cols 4-5: nothing else lands in it.
  EXPECT_EQ(per_pixel[4 * 6 + 4] + per_pixel[4 * 6 + 5], static_cast<int64_t>(count[3]));
}

TEST(ErrorMap, StateContinuesTheSameDraws) {
  auto a = small_map(0.25);
  a.observe(torch::tensor({3L, 40L}), torch::tensor({0.3, 0.6}));
  auto b = small_map(0.25);
  b.set_state(a.state());
  auto ga = gen(5), gb = gen(5);
  EXPECT_TRUE(torch::equal(a.draw(100, ga), b.draw(100, gb)));
  EXPECT_THROW(ErrorMap(1, 5, 6, {4, 0.25}).set_state(a.state()), std::invalid_argument);
}

// The draws go through a tree of fixed-point sums updated ray by ray: after many updates it must
// equal a map rebuilt from the saved errors (the same probabilities to the bit, the same draws), and
// its probabilities the closed form of the errors in double precision.
TEST(ErrorMap, ManyUpdatesEqualAMapRebuiltFromItsState) {
  const int64_t images = 3, h = 37, w = 53;
  ErrorMap a(images, h, w, {4, 0.3});
  auto g = gen(17);
  for (int step = 0; step < 300; ++step) {
    const auto px = torch::randint(images * h * w, {64}, g, torch::kLong);
    a.observe(px, torch::rand({64}, g, torch::kDouble).pow(3) * 2.0);
  }
  ErrorMap b(images, h, w, {4, 0.3});
  b.set_state(a.state());
  EXPECT_TRUE(torch::equal(a.probabilities(), b.probabilities()));
  auto ga = gen(9), gb = gen(9);
  EXPECT_TRUE(torch::equal(a.draw(5000, ga), b.draw(5000, gb)));
  // The closed form, each tile's drawable pixels counted from its rectangle.
  const auto st = a.state();
  const int64_t tx = (w + 3) / 4, ty = (h + 3) / 4;
  ASSERT_EQ(a.tiles(), images * tx * ty);
  const double sum = st.slice(0, 1).sum().item<double>();
  const auto p = a.probabilities();
  for (int64_t t = 0; t < a.tiles(); ++t) {
    const int64_t in_image = t % (tx * ty), row = in_image / tx * 4, col = in_image % tx * 4;
    const double area = static_cast<double>(std::min<int64_t>(4, h - row) * std::min<int64_t>(4, w - col));
    const double want = 0.3 * area / static_cast<double>(images * h * w) + 0.7 * st[t + 1].item<double>() / sum;
    ASSERT_NEAR(p[t].item<double>(), want, 1e-9 * want) << t;
  }
}

// A mask (a capture's masks, Split::mask): tiles count their kept pixels only, a tile without any
// is never drawn, and a ray lands on one of its tile's kept pixels, each equally likely.
TEST(ErrorMap, MaskedPixelsAreNeverDrawnAndTheRestUniformly) {
  // small_map's layout (2 images of 5 x 6, tiles of 4). Image 0 keeps columns 0-2 of every row
  // (tile 0: 12 px, tile 1: 0, tile 2: 3, tile 3: 0); image 1 keeps everything but row 0 (tile 4:
  // 12, tile 5: 6, tile 6: 4, tile 7: 2). 39 kept pixels.
  auto keep = torch::zeros({2, 5, 6}, torch::kBool);
  keep[0].slice(1, 0, 3).fill_(true);
  keep[1].slice(0, 1, 5).fill_(true);
  ErrorMap map(2, 5, 6, {4, 0.25}, keep);
  const double kept[8] = {12, 0, 3, 0, 12, 6, 4, 2};
  auto p = map.probabilities();
  for (int t = 0; t < 8; ++t) EXPECT_NEAR(p[t].item<double>(), kept[t] / 39.0, 1e-15) << t;
  // Errors seen (pixels of tiles 0, 0 and 4; the first observation seeds every tile, tiles 1 and 3
  // included): tiles without kept pixels still get no share of the error part.
  map.observe(torch::tensor({0L, 3L, 36L}), torch::tensor({0.4, 0.4, 0.2}));
  p = map.probabilities();
  EXPECT_EQ(p[1].item<double>(), 0.0);
  EXPECT_EQ(p[3].item<double>(), 0.0);
  auto g = gen(5);
  const int64_t n = 100000;
  const auto idx = map.draw(n, g);
  std::vector<int64_t> per_pixel(60, 0);
  for (int64_t i = 0; i < n; ++i) per_pixel[static_cast<size_t>(idx[i].item<int64_t>())]++;
  const auto k = keep.reshape({-1});
  for (int64_t px = 0; px < 60; ++px) {
    if (!k[px].item<bool>())
      EXPECT_EQ(per_pixel[static_cast<size_t>(px)], 0) << px;
    else
      EXPECT_GT(per_pixel[static_cast<size_t>(px)], 0) << px;
  }
  // Tile 0 of image 0 keeps rows 0-3 x cols 0-2: its 12 counts equally likely (chi-square, 11
  // degrees of freedom, 99.99th percentile 35.7).
  double in_tile = 0;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 3; ++c) in_tile += static_cast<double>(per_pixel[static_cast<size_t>(r * 6 + c)]);
  double chi2 = 0;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 3; ++c) {
      const double d = static_cast<double>(per_pixel[static_cast<size_t>(r * 6 + c)]) - in_tile / 12;
      chi2 += d * d / (in_tile / 12);
    }
  EXPECT_LT(chi2, 35.7);
  // A mask that keeps nothing, or of another size, is refused.
  EXPECT_THROW(ErrorMap(2, 5, 6, {4, 0.25}, torch::zeros({2, 5, 6}, torch::kBool)), std::invalid_argument);
  EXPECT_THROW(ErrorMap(2, 5, 6, {4, 0.25}, torch::ones({2, 6, 5}, torch::kBool)), std::invalid_argument);
}
