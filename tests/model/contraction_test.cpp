// Stage 1b (unbounded scenes): the contraction of points and frustum Gaussians, and the sample
// spacing, against independent references: closed forms, the full 3x3 covariance pushed through an
// autograd Jacobian, and Monte Carlo samples pushed through the map.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>

#include "model/contraction.h"
#include "model/frustum.h"

using namespace ablenerf;

namespace {

// The Jacobian of contract_points at x (3,), by autograd, one output component at a time.
torch::Tensor autograd_jacobian(const torch::Tensor& x) {
  auto J = torch::zeros({3, 3}, torch::kFloat64);
  for (int64_t c = 0; c < 3; ++c) {
    auto xi = x.detach().clone().requires_grad_(true);
    auto y = contract_points(xi.unsqueeze(0)).squeeze(0);
    auto g = torch::autograd::grad({y[c]}, {xi})[0];
    J[c] = g;
  }
  return J;
}

}  // namespace

TEST(Contraction, PointsClosedForm) {
  auto x = torch::tensor({{0.3, -0.4, 0.5}, {2.0, 0.0, 0.0}, {0.0, -4.0, 0.0}, {30.0, 40.0, 0.0}}, torch::kFloat64);
  auto y = contract_points(x);
  // Inside the unit ball: identity.
  EXPECT_TRUE(torch::allclose(y[0], x[0]));
  // |x| = 2 -> radius 2 - 1/2 = 1.5, same direction; |x| = 4 -> 1.75; |x| = 50 -> 1.98.
  EXPECT_NEAR(y[1][0].item<double>(), 1.5, 1e-12);
  EXPECT_NEAR(y[2][1].item<double>(), -1.75, 1e-12);
  EXPECT_NEAR(y[3][0].item<double>(), 0.6 * 1.98, 1e-12);
  EXPECT_NEAR(y[3][1].item<double>(), 0.8 * 1.98, 1e-12);
  // Continuous at the unit sphere and always inside radius 2.
  auto near1 = torch::tensor({{0.0, 0.0, 1.0 + 1e-9}}, torch::kFloat64);
  EXPECT_NEAR(contract_points(near1)[0][2].item<double>(), 1.0, 1e-8);
  auto far = torch::randn({1000, 3}, torch::kFloat64) * 1e6;
  EXPECT_LT(contract_points(far).norm(2, -1).max().item<double>(), 2.0);
}

TEST(Contraction, CovarianceDiagonalEqualsJacobianSandwichOfTheFullCovariance) {
  // Rays from inside and outside the unit ball, samples on both sides of the sphere.
  torch::manual_seed(3);
  const int64_t B = 4, S = 6;
  auto origins =
      torch::tensor({{0.1, 0.2, -0.3}, {0.0, 0.9, 0.1}, {1.5, -0.5, 0.2}, {-0.2, 0.1, 0.0}}, torch::kFloat64);
  auto dirs = torch::tensor({{1.0, 0.3, -0.2}, {0.2, -1.1, 0.4}, {-0.7, 0.6, 0.9}, {0.0, 0.0, -1.0}}, torch::kFloat64);
  auto t = torch::linspace(0.05, 6.0, S + 1, torch::kFloat64).expand({B, S + 1}).contiguous();
  auto radius = torch::full({B, 1}, 0.02, torch::kFloat64);
  const auto m = conical_frustum_moments(t.slice(1, 0, S), t.slice(1, 1, S + 1), radius);
  const auto mean = origins.unsqueeze(1) + dirs.unsqueeze(1) * m.t_mean.unsqueeze(-1);
  const auto got = contract_gaussians(mean, dirs, m);
  int outside = 0;
  for (int64_t b = 0; b < B; ++b) {
    const auto d = dirs[b];
    const auto ddT = torch::outer(d, d);
    for (int64_t s = 0; s < S; ++s) {
      // The frustum's full covariance (mip-NeRF eq. 8): t_var d d^T + r_var (I - d d^T / |d|^2).
      const double tv = m.t_var[b][s].item<double>(), rv = m.r_var[b][s].item<double>();
      const auto Sfull = tv * ddT + rv * (torch::eye(3, torch::kFloat64) - ddT / d.dot(d));
      const auto x = mean[b][s];
      outside += x.norm().item<double>() > 1;
      const auto J = autograd_jacobian(x);
      const auto want = torch::diagonal(J.mm(Sfull).mm(J.t()));
      EXPECT_TRUE(torch::allclose(got.cov[b][s], want, 1e-9, 1e-15))
          << "b " << b << " s " << s << " got " << got.cov[b][s] << " want " << want;
      EXPECT_TRUE(torch::allclose(got.mean[b][s], contract_points(x.unsqueeze(0))[0]));
    }
  }
  EXPECT_GT(outside, 5);  // the samples exercise the contracted branch
  EXPECT_LT(outside, B * S);
}

TEST(Contraction, MonteCarloVarianceOfContractedSamples) {
  // A small Gaussian outside the unit ball: the variance of contracted samples matches the
  // linearised diagonal to the Monte Carlo error.
  const auto mean = torch::tensor({{{1.6, -0.8, 0.9}}}, torch::kFloat64);  // (1,1,3)
  const auto d = torch::tensor({{0.6, -0.3, 0.74}}, torch::kFloat64);
  FrustumMoments m;
  m.t_mean = torch::ones({1, 1}, torch::kFloat64);
  m.t_var = torch::full({1, 1}, 4e-4, torch::kFloat64);
  m.r_var = torch::full({1, 1}, 1e-4, torch::kFloat64);
  const auto got = contract_gaussians(mean, d, m).cov[0][0];
  const auto dv = d[0];
  const auto ddT = torch::outer(dv, dv);
  const auto Sfull = 4e-4 * ddT + 1e-4 * (torch::eye(3, torch::kFloat64) - ddT / dv.dot(dv));
  const auto L = torch::linalg_cholesky(Sfull);  // (torch::linalg:: needs torch/linalg.h in LibTorch 2.x)
  auto gen = at::detail::createCPUGenerator(11);
  const int64_t n = 400000;
  const auto z = at::normal(0.0, 1.0, {n, 3}, gen).to(torch::kFloat64);
  const auto samples = mean[0][0] + z.mm(L.t());
  const auto var = contract_points(samples).var(0);
  for (int c = 0; c < 3; ++c) {
    const double w = got[c].item<double>();
    // Standard error of a sample variance: w sqrt(2/n) (~0.2%); 3% covers the linearisation.
    EXPECT_NEAR(var[c].item<double>(), w, 0.03 * w) << "axis " << c;
  }
}

TEST(Contraction, UnboundedDepthsLinearThenLinearInDisparity) {
  const double near = 0.2, far = 1e6;
  const double pivot = 1.0;  // max(1, 2 near)
  auto s = torch::linspace(0, 1, 11, torch::kFloat64);
  auto t = unbounded_depths(s, near, far);
  EXPECT_NEAR(t[0].item<double>(), near, 1e-12);
  EXPECT_NEAR(t[5].item<double>(), pivot, 1e-12);
  EXPECT_NEAR(t[10].item<double>(), far, far * 1e-9);
  // First half: equal steps in depth; second half: equal steps in 1/t.
  for (int i = 1; i < 5; ++i) EXPECT_NEAR(t[i + 1].item<double>() - t[i].item<double>(), (pivot - near) / 5, 1e-12);
  for (int i = 5; i < 10; ++i)
    EXPECT_NEAR(1 / t[i].item<double>() - 1 / t[i + 1].item<double>(), (1 / pivot - 1 / far) / 5, 1e-12);
  // Monotone, and a near beyond 0.5 moves the pivot to 2 near.
  EXPECT_TRUE((t.slice(0, 1) > t.slice(0, 0, 10)).all().item<bool>());
  EXPECT_NEAR(unbounded_depths(torch::tensor({0.5}, torch::kFloat64), 0.8, far)[0].item<double>(), 1.6, 1e-12);
}
