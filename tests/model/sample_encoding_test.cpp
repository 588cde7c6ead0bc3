// The samples' Gaussians and encoding in one loop (kernels/sample_encoding_cpu.h) against the plain
// path of the model's stages (model/frustum.h, model/contraction.h, model/ipe.h) computed in
// float64: bounded and contracted scenes, the grid's unit coordinates and level weights, samples inside and outside the
// unit ball, encodings of one sample, a block's tail and several blocks, every vector form this CPU runs; the whole
// model under "fused" against "plain"; bad inputs refused naming the argument.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include "kernels/kernel_test_util.h"
#include "kernels/sample_encoding_cpu.h"
#include "model/able_nerf.h"
#include "model/compute.h"
#include "model/contraction.h"
#include "model/frustum.h"
#include "model/grid_embedding.h"
#include "model/ipe.h"
#include "model/model_config.h"
#include "test_util.h"

namespace ablenerf {
namespace {

// Rays from around the origin with unnormalised directions, cone radii of a few thousandths, and
// increasing fence posts from 0.05 to 12: the contracted scene's samples fall inside the unit ball
// and far outside it.
struct SampleCase {
  torch::Tensor t;
  Rays rays;
};

SampleCase sample_case(int64_t b, int64_t s, uint64_t seed) {
  SampleCase c;
  c.rays.origins = test::seeded_randn({b, 3}, seed, 0.5).to(torch::kFloat);
  c.rays.directions = test::seeded_randn({b, 3}, seed + 1).to(torch::kFloat);
  c.rays.radii = (test::seeded_randn({b, 1}, seed + 2, 0.001, 0.003).abs() + 1e-4).to(torch::kFloat);
  const auto steps = test::seeded_randn({b, s + 1}, seed + 3).abs() + 0.05;
  c.t = (steps.cumsum(-1) * (12.0 / (s + 1))).to(torch::kFloat);
  return c;
}

Rays to_double(const Rays& r) {
  return {r.origins.to(torch::kDouble), r.directions.to(torch::kDouble), r.radii.to(torch::kDouble)};
}

void expect_close(const torch::Tensor& got, const torch::Tensor& want, double rtol, const std::string& what) {
  ASSERT_EQ(got.sizes(), want.sizes()) << what;
  const auto err = (got.to(torch::kDouble) - want).abs();
  const auto bound = rtol * (want.abs() + want.abs().max() * 1e-3);
  EXPECT_TRUE((err <= bound).all().item<bool>()) << what << ": worst excess " << (err - bound).max().item<double>();
}

TEST(SampleEncoding, GaussiansMatchTheModelsStagesBoundedAndContracted) {
  const SampleCase c = sample_case(37, 16, 5);
  for (const bool contract : {false, true}) {
    const SampleGaussians got = sample_gaussians_cpu(c.t, c.rays.origins, c.rays.directions, c.rays.radii, contract);
    const auto t = c.t.to(torch::kDouble);
    const Gaussians want = contract ? contract_intervals(t, to_double(c.rays)) : cast_intervals(t, to_double(c.rays));
    const std::string what = contract ? "contracted" : "bounded";
    expect_close(got.mean, want.mean, 1e-5, what + " mean");
    expect_close(got.cov, want.cov, 1e-4, what + " cov");
    if (contract) {
      // Both sides of the unit ball are exercised, and the contracted means stay within radius 2.
      const auto r = want.mean.norm(2, -1);
      EXPECT_TRUE((r < 1).any().item<bool>());
      EXPECT_TRUE((r > 1.5).any().item<bool>());
      EXPECT_LT(got.mean.norm(2, -1).max().item<double>(), 2.0);
    }
  }
}

TEST(SampleEncoding, EncodingMatchesTheModelsIpeInEveryForm) {
  int ran = 0;
  for (const CpuVectorForm form : {CpuVectorForm::Scalar, CpuVectorForm::Avx512}) {
    // The Avx512 form needs Sleef as well as the CPU: refused, naming the op, where either lacks.
    if (!cpu_vector_form_available(form)) continue;
    for (const int64_t n : {int64_t(1), int64_t(63), int64_t(65), int64_t(200)})
      for (const int64_t degrees : {int64_t(1), int64_t(4), int64_t(10)}) {
        const auto mean = test::seeded_randn({n, 3}, uint64_t(n + degrees), 1.0).to(torch::kFloat);
        const auto cov = test::seeded_randn({n, 3}, uint64_t(n + degrees + 7), 0.02).abs().to(torch::kFloat);
        torch::Tensor got;
        try {
          got = integrated_pos_enc_cpu(mean, cov, degrees, form);
        } catch (const c10::Error& e) {
          EXPECT_NE(std::string(e.what()).find("integrated_pos_enc_cpu"), std::string::npos);
          EXPECT_NE(form, CpuVectorForm::Scalar);
          // Refused only where the model does not take these loops either (no Sleef in the build).
          EXPECT_FALSE(sample_encoding_cpu_available({mean, cov}));
          continue;
        }
        ++ran;
        // The reference from the same float32 angles (2^l mean is exact; y + pi/2 rounds alike).
        const auto want = integrated_pos_enc(mean, cov, degrees);
        const double err = test::max_abs(got - want);
        EXPECT_LT(err, 2e-6) << "form " << static_cast<int>(form) << " n " << n << " degrees " << degrees;
        EXPECT_EQ(got.sizes(), want.sizes());
      }
  }
  // The scalar form always; the AVX-512 form too wherever the model runs these loops.
  EXPECT_EQ(ran, sample_encoding_cpu_available({torch::zeros({1, 3})}) ? 24 : 12);
}

TEST(SampleEncoding, GridInputsMatchTheGridsWeightsInEveryForm) {
  // Points in and out of the cube [-2, 2]^3 (its faces included), variances from none (every level
  // read whole) to wide (the fine levels faded out).
  const int64_t n = 67;
  auto mean = test::seeded_randn({n, 3}, 21, 1.5).to(torch::kFloat);
  mean[0] = torch::tensor({2.0f, -2.0f, 0.0f});   // on the faces: inside
  mean[1] = torch::tensor({2.001f, 0.0f, 0.0f});  // just outside
  auto cov = (test::seeded_randn({n, 3}, 22, 1.0).abs() * 1e-3).to(torch::kFloat);
  cov[2] = torch::zeros({3});
  cov[3] = torch::full({3}, 0.5f);
  const auto res = torch::tensor({16.0f, 45.0f, 128.0f, 362.0f, 1024.0f});
  const double lo = -2, hi = 2, scale = 5;
  const auto unit = (mean - lo) / (hi - lo);
  const auto inside = ((unit >= 0) & (unit <= 1)).all(-1, /*keepdim=*/true);
  const auto want = grid_level_weights(cov.mean(-1) / ((hi - lo) * (hi - lo)), res) * inside * scale;
  ASSERT_TRUE(inside[0].item<bool>());
  ASSERT_FALSE(inside[1].item<bool>());
  int ran = 0;
  for (const CpuVectorForm form : {CpuVectorForm::Scalar, CpuVectorForm::Avx512}) {
    if (!cpu_vector_form_available(form)) continue;
    GridInputs got;
    try {
      got = grid_inputs_cpu(mean, cov, lo, hi, res, scale, form);
    } catch (const c10::Error& e) {
      EXPECT_NE(std::string(e.what()).find("grid_inputs_cpu"), std::string::npos);
      EXPECT_NE(form, CpuVectorForm::Scalar);
      EXPECT_FALSE(sample_encoding_cpu_available({mean, cov}));
      continue;
    }
    ++ran;
    EXPECT_LT(test::max_abs(got.unit - unit), 1e-6) << static_cast<int>(form);
    ASSERT_EQ(got.weights.sizes(), want.sizes());
    EXPECT_LT(test::max_abs(got.weights - want), 2e-6 * scale) << static_cast<int>(form);
    EXPECT_FLOAT_EQ(got.weights[2][4].item<float>(), float(scale));  // no variance: every level whole
    EXPECT_EQ(got.weights[1].abs().sum().item<float>(), 0.0f);       // outside: nothing read
    EXPECT_TRUE(torch::equal(got.inside, inside.squeeze(-1).to(torch::kFloat))) << static_cast<int>(form);
  }
  EXPECT_EQ(ran, sample_encoding_cpu_available({mean, cov}) ? 2 : 1);
  // Through the module: the grid's features alike with the loop and with the tensor ops.
  GridEmbedding grid(hash_grid_shape(5, 2, 12, 16, 1024), GridCube{lo, hi}, scale);
  {
    torch::NoGradGuard no_grad;
    grid->table_parameter().uniform_(-1e-2, 1e-2);
  }
  torch::Tensor features[2];
  for (int i = 0; i < 2; ++i) {
    grid->set_fused_inputs(i == 0);
    torch::NoGradGuard no_grad;
    features[i] = grid(mean, cov);
  }
  EXPECT_LT(test::max_abs(features[0] - features[1]), 1e-6);
  EXPECT_GT(test::max_abs(features[1]), 1e-4);
}

TEST(SampleEncoding, TheWholeModelAgreesWithThePlainPath) {
  ModelConfig cfg;
  cfg.width = 32;
  cfg.heads = 2;
  cfg.ff_ratio = 2;
  cfg.samples = 16;
  cfg.embedding = Embedding::Grid;
  cfg.grid_levels = 4;
  cfg.grid_log2_table = 12;
  cfg.grid_max_resolution = 64;
  cfg.grid_ipe_degrees = 4;
  cfg.proposal_samples = 16;
  cfg.le_count = 4;
  torch::manual_seed(3);
  AbleNerf model(cfg, SceneKind::Unbounded);
  model->eval();
  const Rays rays = test::random_rays(24, 11);
  torch::NoGradGuard no_grad;
  ModelOutput out[2];
  for (int i = 0; i < 2; ++i) {
    Compute c;
    c.attention = i == 0 ? AttentionKernel::Fused : AttentionKernel::Plain;
    model->set_compute(c);
    out[i] = model->forward(rays, 0.2, 20.0);
  }
  EXPECT_LT(test::max_abs(out[0].rgb_fine - out[1].rgb_fine), 1e-4);
  EXPECT_LT(test::max_abs(out[0].fine_s - out[1].fine_s), 1e-4);
}

TEST(SampleEncoding, BadInputsAreRefusedNamingTheArgument) {
  const SampleCase c = sample_case(4, 8, 1);
  test::expect_error_naming(
      [&] { sample_gaussians_cpu(c.t, c.rays.origins.slice(1, 0, 2), c.rays.directions, c.rays.radii, true); },
      "sample_gaussians_cpu: origins");
  test::expect_error_naming(
      [&] { sample_gaussians_cpu(c.t, c.rays.origins, c.rays.directions, c.rays.radii.squeeze(1), true); },
      "sample_gaussians_cpu: radii");
  test::expect_error_naming(
      [&] { sample_gaussians_cpu(c.t.to(torch::kDouble), c.rays.origins, c.rays.directions, c.rays.radii, false); },
      "sample_gaussians_cpu: t");
  const auto m = torch::zeros({5, 3});
  test::expect_error_naming([&] { integrated_pos_enc_cpu(m, torch::zeros({5, 2}), 4); }, "integrated_pos_enc_cpu: cov");
  test::expect_error_naming([&] { integrated_pos_enc_cpu(m, m, 0); }, "integrated_pos_enc_cpu: degrees");
  test::expect_error_naming(
      [&] {
        grid_inputs_cpu(m, m, -1, 1, torch::ones({2, 2}), 1);
      },
      "grid_inputs_cpu: resolution");
  test::expect_error_naming([&] { grid_inputs_cpu(m, m, 1, 1, torch::ones({2}), 1); }, "grid_inputs_cpu: the cube");
  // Not for inputs autograd has to differentiate.
  EXPECT_FALSE(sample_encoding_cpu_available({m.clone().requires_grad_()}));
}

}  // namespace
}  // namespace ablenerf
