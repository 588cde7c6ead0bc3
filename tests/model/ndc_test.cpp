// Stage 1b (forward-facing scenes): NDC rays against independent references: the projective
// point map by hand (points on a ray land on its NDC ray, in order, z = -1 -> -1, infinity -> 1),
// and multinerf's radius rule (the mean NDC offset between the origins of neighbouring pixels'
// rays) computed here from real neighbouring pixel rays.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <vector>

#include "data/rays.h"
#include "model/ndc.h"

using namespace ablenerf;

namespace {

// The NDC image of a point by hand (near plane 1).
std::array<double, 3> ndc_point(double x, double y, double z, double a, double b) {
  return {-a * x / z, -b * y / z, 1 + 2 / z};
}

}  // namespace

TEST(Ndc, PointsOfARayLieOnItsNdcRayInOrder) {
  const NdcProjection p{1.7, 2.3};
  auto origins = torch::tensor({{0.1, -0.2, 0.05}, {-0.3, 0.1, -0.2}, {0.0, 0.0, 0.0}}, torch::kFloat64);
  auto dirs = torch::tensor({{0.2, 0.1, -1.0}, {-0.1, 0.25, -1.0}, {0.0, 0.0, -1.0}}, torch::kFloat64);
  const Rays in{origins, dirs, torch::full({3, 1}, 1e-3, torch::kFloat64)};
  const Rays r = rays_to_ndc(in, p);
  for (int64_t i = 0; i < 3; ++i) {
    // The NDC origin is the image of the ray's point on z = -1.
    const double t1 = (-1 - origins[i][2].item<double>()) / dirs[i][2].item<double>();
    const auto o1 = origins[i] + t1 * dirs[i];
    const auto want_o = ndc_point(o1[0].item<double>(), o1[1].item<double>(), o1[2].item<double>(), p.a, p.b);
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(r.origins[i][k].item<double>(), want_o[static_cast<size_t>(k)], 1e-12);
    EXPECT_NEAR(r.origins[i][2].item<double>(), -1, 1e-12);
    // Farther points map to larger t' in [0, 1), along the NDC ray.
    double last = -1;
    for (double t : {0.5, 1.0, 3.0, 10.0, 1000.0}) {
      const auto x = o1 + t * dirs[i];
      const auto q = ndc_point(x[0].item<double>(), x[1].item<double>(), x[2].item<double>(), p.a, p.b);
      const double s = (q[2] - r.origins[i][2].item<double>()) / r.directions[i][2].item<double>();
      for (int k = 0; k < 2; ++k)
        EXPECT_NEAR(r.origins[i][k].item<double>() + s * r.directions[i][k].item<double>(), q[static_cast<size_t>(k)],
                    1e-9);
      EXPECT_GT(s, last);
      EXPECT_LT(s, 1.0);
      last = s;
    }
    // Infinity is t' = 1: z' = o'_z + d'_z = 1.
    EXPECT_NEAR(r.origins[i][2].item<double>() + r.directions[i][2].item<double>(), 1.0, 1e-12);
  }
  // points_to_ndc is the same map.
  const auto q = points_to_ndc(torch::tensor({{0.3, -0.4, -2.0}}, torch::kFloat64), p);
  EXPECT_NEAR(q[0][0].item<double>(), -1.7 * 0.3 / -2.0, 1e-12);
  EXPECT_NEAR(q[0][2].item<double>(), 0.0, 1e-12);
}

TEST(Ndc, RadiusIsTheNdcOffsetBetweenNeighbouringPixels) {
  // A 40x30 camera at (0.1, -0.05, 0.2) looking down -z: for each pixel, the NDC origins of its
  // right-hand and lower neighbours (real rays of those pixels) give multinerf's radius.
  Intrinsics k;
  k.width = 40, k.height = 30, k.fx = 34, k.fy = 34, k.cx = 20, k.cy = 15;
  auto c2w = torch::eye(4, torch::kFloat64).slice(0, 0, 3).clone();
  c2w[0][3] = 0.1, c2w[1][3] = -0.05, c2w[2][3] = 0.2;
  const NdcProjection p{2 * k.fx / k.width, 2 * k.fy / k.height};
  const Rays rays = rays_for_image(c2w, k);  // row-major, H*W
  const Rays ndc = rays_to_ndc(
      Rays{rays.origins.to(torch::kFloat64), rays.directions.to(torch::kFloat64), rays.radii.to(torch::kFloat64)}, p);
  const auto o = ndc.origins.reshape({30, 40, 3});
  const auto dx = (o.slice(1, 1).slice(0, 0, 29) - o.slice(1, 0, 39).slice(0, 0, 29)).norm(2, -1);  // (29, 39)
  const auto dy = (o.slice(0, 1).slice(1, 0, 39) - o.slice(0, 0, 29).slice(1, 0, 39)).norm(2, -1);
  const auto want = 0.5 * (dx + dy) * (2 / std::sqrt(12.0));
  const auto got = ndc.radii.reshape({30, 40}).slice(0, 0, 29).slice(1, 0, 39);
  EXPECT_LT(((got - want).abs() / want).max().item<double>(), 1e-3);
  // By hand: the camera is 1.2 from the near plane, so one pixel moves the NDC origin by
  // a * 1.2 / fx = 2.4 / W in x (and 2.4 / H in y).
  EXPECT_NEAR((o[15][39][0] - o[15][38][0]).item<double>(), 2.4 / 40, 1e-6);
  EXPECT_NEAR((o[14][20][1] - o[15][20][1]).item<double>(), 2.4 / 30, 1e-6);
}

// depth_from_ndc inverts the map: a point at a known depth along a scene-frame ray, projected by
// hand and read off its NDC ray as t', comes back as that depth (for rays starting before and
// behind the near plane, tilted, and at every depth from the near plane to far away).
TEST(Ndc, DepthFromNdcRecoversTheDepthOfAPointOnTheRay) {
  const NdcProjection p{1.3, 0.9};
  const auto origins = torch::tensor({{0.1, -0.2, 0.05}, {-0.3, 0.1, -0.2}, {0.4, 0.2, -0.5}}, torch::kFloat64);
  const auto dirs = torch::tensor({{0.2, 0.1, -1.0}, {-0.1, 0.25, -1.0}, {0.05, -0.3, -1.0}}, torch::kFloat64);
  const Rays in{origins, dirs, torch::full({3, 1}, 1e-3, torch::kFloat64)};
  const Rays r = rays_to_ndc(in, p);
  for (double depth : {1.2, 2.0, 7.5, 40.0, 900.0}) {
    std::vector<double> t_ndc;
    for (int64_t i = 0; i < 3; ++i) {
      const auto x = origins[i] + depth * dirs[i];
      const auto q = ndc_point(x[0].item<double>(), x[1].item<double>(), x[2].item<double>(), p.a, p.b);
      t_ndc.push_back((q[2] - r.origins[i][2].item<double>()) / r.directions[i][2].item<double>());
    }
    const auto back = depth_from_ndc(in, torch::tensor(t_ndc, torch::kFloat64));
    ASSERT_EQ(back.sizes(), torch::IntArrayRef({3}));
    for (int64_t i = 0; i < 3; ++i) EXPECT_NEAR(back[i].item<double>(), depth, 1e-9 * depth) << "ray " << i;
  }
  // Shape (B,1) is kept; t' = 0 is the near plane z = -1.
  const auto at_near = depth_from_ndc(in, torch::zeros({3, 1}, torch::kFloat64));
  ASSERT_EQ(at_near.sizes(), torch::IntArrayRef({3, 1}));
  for (int64_t i = 0; i < 3; ++i) {
    const double want = (-1 - origins[i][2].item<double>()) / dirs[i][2].item<double>();
    EXPECT_NEAR(at_near[i][0].item<double>(), want, 1e-12);
  }
}
