// Stage 1: frustum moments and their 3-D lift against brute-force numerical integration over
// the cone (uniform density inside the truncated cone, disc radius r t perpendicular to d).
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <array>
#include <cmath>

#include "model/frustum.h"
#include "test_util.h"

namespace ablenerf {
namespace {

// Composite Simpson weights on [a,b] with n (even) panels.
std::vector<std::pair<double, double>> simpson(double a, double b, int n) {
  std::vector<std::pair<double, double>> nodes;
  const double h = (b - a) / n;
  for (int i = 0; i <= n; ++i) {
    const double w = (i == 0 || i == n) ? 1.0 : (i % 2 ? 4.0 : 2.0);
    nodes.emplace_back(a + i * h, w * h / 3.0);
  }
  return nodes;
}

struct Moments1D {
  double t_mean, t_var, r_var;
};

// Density ~ t^2 on [t0,t1] (disc area grows as t^2); r_var = E[(r t)^2] / 4.
Moments1D reference_moments(double t0, double t1, double r) {
  const auto nodes = simpson(t0, t1, 2000);
  double z = 0, m1 = 0;
  for (auto [t, w] : nodes) z += w * t * t, m1 += w * t * t * t;
  const double mean = m1 / z;
  double var = 0, t2 = 0;
  for (auto [t, w] : nodes) var += w * t * t * (t - mean) * (t - mean), t2 += w * t * t * t * t;
  return {mean, var / z, r * r * (t2 / z) / 4.0};
}

struct Moments3D {
  std::array<double, 3> mean, var;
};

// Integrates over t, the disc radius rho in [0, r t] (area element rho) and the angle phi.
Moments3D reference_cone(std::array<double, 3> o, std::array<double, 3> d, double r, double t0, double t1) {
  const double dn = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
  const std::array<double, 3> dh{d[0] / dn, d[1] / dn, d[2] / dn};
  // Orthonormal u, v perpendicular to d.
  std::array<double, 3> a{1, 0, 0};
  std::array<double, 3> u{dh[1] * a[2] - dh[2] * a[1], dh[2] * a[0] - dh[0] * a[2], dh[0] * a[1] - dh[1] * a[0]};
  const double un = std::sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
  for (auto& x : u) x /= un;
  const std::array<double, 3> v{dh[1] * u[2] - dh[2] * u[1], dh[2] * u[0] - dh[0] * u[2], dh[0] * u[1] - dh[1] * u[0]};
  const int n_phi = 32;
  double z = 0;
  std::array<double, 3> s1{}, s2{};
  for (auto [t, wt] : simpson(t0, t1, 200)) {
    for (auto [rho, wr] : simpson(0.0, r * t, 20)) {
      for (int k = 0; k < n_phi; ++k) {
        const double phi = 2 * M_PI * k / n_phi, c = std::cos(phi), s = std::sin(phi);
        const double w = wt * wr * rho;
        z += w;
        for (int i = 0; i < 3; ++i) {
          const double x = o[i] + t * d[i] + rho * (c * u[i] + s * v[i]);
          s1[i] += w * x;
          s2[i] += w * x * x;
        }
      }
    }
  }
  Moments3D m;
  for (int i = 0; i < 3; ++i) {
    m.mean[i] = s1[i] / z;
    m.var[i] = s2[i] / z - m.mean[i] * m.mean[i];
  }
  return m;
}

torch::Tensor scalar(double v, torch::Dtype dt) { return torch::full({1, 1}, v, torch::TensorOptions(dt)); }

TEST(Frustum, MomentsMatchQuadratureInDouble) {
  const double r = 0.03;
  for (auto [t0, t1] :
       std::vector<std::pair<double, double>>{{2.0, 2.0 + 1e-4}, {2.0, 2.0417}, {2.0, 6.0}, {0.0, 1.0}, {0.5, 10.0}}) {
    const auto ref = reference_moments(t0, t1, r);
    const auto m =
        conical_frustum_moments(scalar(t0, torch::kDouble), scalar(t1, torch::kDouble), scalar(r, torch::kDouble));
    EXPECT_NEAR(m.t_mean.item<double>(), ref.t_mean, 1e-9 * ref.t_mean) << t0 << " " << t1;
    EXPECT_NEAR(m.t_var.item<double>(), ref.t_var, 1e-6 * ref.t_var) << t0 << " " << t1;
    EXPECT_NEAR(m.r_var.item<double>(), ref.r_var, 1e-9 * ref.r_var) << t0 << " " << t1;
  }
}

TEST(Frustum, StableFormKeepsTinyIntervalsAccurateInFloat) {
  // A 1e-4 interval at t = 2: naive (t1^3 - t0^3) forms lose everything in float32.
  const double t0 = 2.0, t1 = 2.0 + 1e-4, r = test::kBlenderPixelRadius;
  const auto ref = reference_moments(t0, t1, r);
  const auto m =
      conical_frustum_moments(scalar(t0, torch::kFloat), scalar(t1, torch::kFloat), scalar(r, torch::kFloat));
  EXPECT_NEAR(m.t_var.item<double>(), ref.t_var, 1e-2 * ref.t_var);
  EXPECT_NEAR(m.r_var.item<double>(), ref.r_var, 1e-5 * ref.r_var);
}

TEST(Frustum, LiftedGaussianMatchesConeIntegration) {
  const std::array<double, 3> o{0.3, -0.2, 0.5}, d{0.4, -0.7, 1.3};  // unnormalised on purpose
  const double r = 0.05;
  const auto opts = torch::TensorOptions(torch::kDouble);
  const Rays rays{torch::tensor({o[0], o[1], o[2]}, opts).view({1, 3}),
                  torch::tensor({d[0], d[1], d[2]}, opts).view({1, 3}), torch::full({1, 1}, r, opts)};
  for (auto [t0, t1] : std::vector<std::pair<double, double>>{{3.0, 3.001}, {2.0, 2.5}, {2.0, 6.0}}) {
    const auto g = cast_intervals(torch::tensor({t0, t1}, opts).view({1, 2}), rays);
    ASSERT_EQ(g.mean.sizes(), (std::vector<int64_t>{1, 1, 3}));
    const auto ref = reference_cone(o, d, r, t0, t1);
    for (int c = 0; c < 3; ++c) {
      EXPECT_NEAR(g.mean[0][0][c].item<double>(), ref.mean[c], 1e-8) << c;
      EXPECT_NEAR(g.cov[0][0][c].item<double>(), ref.var[c], 1e-6 * ref.var[c] + 1e-12) << c << " " << t0 << " " << t1;
    }
  }
}

}  // namespace
}  // namespace ablenerf
