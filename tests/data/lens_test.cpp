// Lens models and the undistorting ray generator (data/lens.h, data/rays.h) against closed forms,
// round trips over whole images, and a scalar projection written here independently.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>

#include "data/lens.h"
#include "data/rays.h"

using namespace ablenerf;

namespace {

torch::Tensor f64(std::initializer_list<double> v) { return torch::tensor(std::vector<double>(v), torch::kDouble); }

Intrinsics camera(LensModel m, std::array<double, kLensCoeffs> d, int w = 64, int h = 48) {
  Intrinsics k;
  k.model = m;
  k.dist = d;
  k.width = w;
  k.height = h;
  k.fx = 50;
  k.fy = 52;
  k.cx = 31.5;
  k.cy = 24.5;
  return k;
}

// Distorted normalised coordinates of the centre of every pixel of an image.
torch::Tensor pixel_grid(const Intrinsics& k) {
  auto v = torch::arange(k.height, torch::kDouble) + 0.5, u = torch::arange(k.width, torch::kDouble) + 0.5;
  auto g = torch::meshgrid({v, u}, "ij");
  return torch::stack({(g[1].reshape(-1) - k.cx) / k.fx, (g[0].reshape(-1) - k.cy) / k.fy}, 1);
}

CameraTable table_for(const Intrinsics& k, int64_t n) { return CameraTable::of({k}).repeat_first(n); }

// A phone-like radial-tangential lens (strong barrel) and a wide fisheye.
const std::array<double, kLensCoeffs> kPhone{-0.28, 0.09, -0.012, 0, 1.5e-3, -8e-4};
const std::array<double, kLensCoeffs> kFisheye{0.05, -0.01, 0.003, -0.0005, 0, 0};

}  // namespace

TEST(Lens, RadialK1InverseIsTheCardanoRoot) {
  // k1 only: r_d = r + k1 r^3 on the x axis; for k1 > 0 the cubic k1 r^3 + r - r_d = 0 has one real
  // root, r = cbrt(q + s) + cbrt(q - s) with q = r_d / (2 k1), s = sqrt(q^2 + 1 / (27 k1^3)).
  const double k1 = 0.3;
  for (double rd : {0.05, 0.4, 0.9, 1.3}) {
    const double q = rd / (2 * k1), s = std::sqrt(q * q + 1.0 / (27 * k1 * k1 * k1));
    const double r = std::cbrt(q + s) + std::cbrt(q - s);
    const auto k = camera(LensModel::RadialTangential, {k1, 0, 0, 0, 0, 0});
    const auto out = undistort_points(table_for(k, 1), f64({rd, 0}).reshape({1, 2}));
    EXPECT_NEAR(out[0][0].item<double>(), r, 1e-12) << rd;
    EXPECT_NEAR(out[0][1].item<double>(), 0.0, 1e-15);
  }
}

TEST(Lens, FisheyeWithoutCoefficientsIsEquidistant) {
  // theta_d = theta: a point at distorted radius rho lies at angle rho from the axis, so its
  // undistorted radius on the plane z = 1 is tan(rho), in the same direction.
  const auto k = camera(LensModel::Fisheye, {0, 0, 0, 0, 0, 0});
  const auto xy = f64({0.3, -0.4, 0.9, 0.2, 1e-9, 0.0}).reshape({3, 2});
  const auto out = undistort_points(table_for(k, 3), xy);
  for (int i = 0; i < 3; ++i) {
    const double rho = xy[i].norm().item<double>();
    const double expect = std::tan(rho) / rho;
    EXPECT_NEAR(out[i][0].item<double>(), xy[i][0].item<double>() * expect, 1e-12);
    EXPECT_NEAR(out[i][1].item<double>(), xy[i][1].item<double>() * expect, 1e-12);
  }
}

TEST(Lens, RoundTripsOverTheWholeImage) {
  // distort(undistort(p)) == p for every pixel centre, to 1e-6 pixels; and the other way round.
  for (const auto& k :
       {camera(LensModel::RadialTangential, kPhone, 640, 480), camera(LensModel::Fisheye, kFisheye, 640, 480),
        camera(LensModel::Pinhole, {0, 0, 0, 0, 0, 0}, 640, 480)}) {
    Intrinsics big = k;
    big.fx = big.fy = 420, big.cx = 319.5, big.cy = 239.5;
    const auto p = pixel_grid(big);
    const auto t = table_for(big, p.size(0));
    const auto und = undistort_points(t, p);
    const auto back = distort_points(t, und);
    const double err_px = ((back - p) * big.fx).abs().max().item<double>();
    EXPECT_LT(err_px, 1e-6) << lens_model_name(big.model);
    const auto again = undistort_points(t, distort_points(t, und));
    EXPECT_LT(((again - und) * big.fx).abs().max().item<double>(), 1e-6) << lens_model_name(big.model);
    if (big.model != LensModel::Pinhole) {
      EXPECT_GT(((und - p) * big.fx).abs().max().item<double>(), 5.0);  // really distorted
    }
  }
}

TEST(Lens, MixedTableGivesEachRowItsOwnModel) {
  const auto a = camera(LensModel::RadialTangential, kPhone), b = camera(LensModel::Fisheye, kFisheye),
             c = camera(LensModel::Pinhole, {0, 0, 0, 0, 0, 0});
  const auto table = CameraTable::of({a, b, c}).index(torch::tensor({0, 1, 2, 1}, torch::kLong));
  const auto xy = f64({0.3, 0.2, 0.3, 0.2, 0.3, 0.2, -0.5, 0.1}).reshape({4, 2});
  const auto out = undistort_points(table, xy);
  const auto one = [&](const Intrinsics& k, int row) {
    return undistort_points(table_for(k, 1), xy.slice(0, row, row + 1))[0];
  };
  EXPECT_TRUE(torch::allclose(out[0], one(a, 0), 0, 1e-15));
  EXPECT_TRUE(torch::allclose(out[1], one(b, 1), 0, 1e-15));
  EXPECT_TRUE(torch::equal(out[2], xy[2]));
  EXPECT_TRUE(torch::allclose(out[3], one(b, 3), 0, 1e-15));
}

TEST(Lens, FootprintStepMatchesDifferencesOfTheInverse) {
  const auto k = camera(LensModel::RadialTangential, kPhone);
  const auto p = pixel_grid(k);
  const auto t = table_for(k, p.size(0));
  const auto und = undistort_points(t, p);
  const double h = 1e-4;
  const auto dy = torch::tensor({0.0, h}, torch::kDouble);
  const auto fd = (undistort_points(t, p + dy) - undistort_points(t, p - dy)) / (2 * h);
  EXPECT_LT((undistorted_step_y(t, und) - fd).abs().max().item<double>(), 1e-6);
  const auto pin = table_for(camera(LensModel::Pinhole, {0, 0, 0, 0, 0, 0}), 3);
  const auto s = undistorted_step_y(pin, und.slice(0, 0, 3));
  EXPECT_TRUE(torch::equal(s.select(1, 0), torch::zeros({3}, torch::kDouble)));
  EXPECT_TRUE(torch::equal(s.select(1, 1), torch::ones({3}, torch::kDouble)));
}

TEST(Lens, RayThroughTheProjectionOfAPointHitsIt) {
  // Scalar projection written here: world point -> camera (OpenGL c2w inverted) -> OpenCV axes ->
  // perspective divide -> OpenCV distortion -> pixel. The ray through that (fractional) pixel must
  // point at the world point.
  const auto k = camera(LensModel::RadialTangential, kPhone);
  const double c = std::cos(0.4), s = std::sin(0.4);
  // c2w: rotation about y by 0.4 rad, camera at (0.5, -0.2, 3).
  const double R[3][3] = {{c, 0, s}, {0, 1, 0}, {-s, 0, c}}, T[3] = {0.5, -0.2, 3};
  auto c2w = torch::zeros({1, 3, 4}, torch::kFloat);
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) c2w[0][i][j] = R[i][j];
    c2w[0][i][3] = T[i];
  }
  for (const auto& X : std::vector<std::array<double, 3>>{{0.1, 0.2, 0.0}, {-0.8, 0.5, -0.3}, {1.2, -0.6, 0.4}}) {
    double pc[3];  // camera frame (OpenGL): R^T (X - T)
    for (int j = 0; j < 3; ++j) pc[j] = R[0][j] * (X[0] - T[0]) + R[1][j] * (X[1] - T[1]) + R[2][j] * (X[2] - T[2]);
    const double x = pc[0] / -pc[2], y = -pc[1] / -pc[2];  // OpenCV: y down, depth -z
    const double r2 = x * x + y * y, rad = 1 + r2 * (kPhone[0] + r2 * (kPhone[1] + r2 * kPhone[2]));
    const double xd = x * rad + 2 * kPhone[4] * x * y + kPhone[5] * (r2 + 2 * x * x);
    const double yd = y * rad + kPhone[4] * (r2 + 2 * y * y) + 2 * kPhone[5] * x * y;
    const double u = k.fx * xd + k.cx, v = k.fy * yd + k.cy;
    const Rays r =
        rays_for_pixels(c2w, torch::tensor({u - 0.5}, torch::kDouble), torch::tensor({v - 0.5}, torch::kDouble), k);
    const auto d = r.directions[0].to(torch::kDouble);
    const auto want = torch::tensor({X[0] - T[0], X[1] - T[1], X[2] - T[2]}, torch::kDouble);
    const double cosang = (d.dot(want) / (d.norm() * want.norm())).item<double>();
    EXPECT_GT(cosang, 1 - 1e-10);
    // Depth along the optical axis is the ray parameter: origin + (-pc_z) d == X.
    EXPECT_LT((r.origins[0].to(torch::kDouble) + d * -pc[2] - torch::tensor({X[0], X[1], X[2]}, torch::kDouble))
                  .abs()
                  .max()
                  .item<double>(),
              1e-5);
  }
}

TEST(Lens, RadiusFollowsTheUndistortedPixelHeight) {
  // Pinhole: 2 / (sqrt(12) fy) everywhere. Barrel distortion stretches the undistorted pixels away
  // from the centre, so the corner rays' radii exceed the centre's.
  const auto pin = camera(LensModel::Pinhole, {0, 0, 0, 0, 0, 0});
  const Rays rp = rays_for_image(torch::eye(4).slice(0, 0, 3), pin);
  EXPECT_NEAR(rp.radii.min().item<double>(), 2 / (std::sqrt(12.0) * pin.fy), 1e-9);
  EXPECT_NEAR(rp.radii.max().item<double>(), 2 / (std::sqrt(12.0) * pin.fy), 1e-9);
  const auto bar = camera(LensModel::RadialTangential, kPhone);
  const Rays rb = rays_for_image(torch::eye(4).slice(0, 0, 3), bar);
  const auto radii = rb.radii.reshape({bar.height, bar.width});
  EXPECT_NEAR(radii[24][31].item<double>(), 2 / (std::sqrt(12.0) * bar.fy), 2e-3 * 2 / (std::sqrt(12.0) * bar.fy));
  EXPECT_GT(radii[0][0].item<double>(), 1.2 * radii[24][31].item<double>());
}
