// The hash-grid encoding (kernels/hash_grid.h) on the CPU: the level resolutions and the spatial hash
// against their closed forms, exactness on a field that is linear inside a cell, the CPU loops
// against the plain LibTorch reference (values, the table's and the positions' gradients), the
// reference's gradient against finite differences, the loops' gradient the same with one thread and with several, and
// the input checks; every row width the loops are compiled for, and every instruction form this CPU
// runs (the AVX-512 gather and scatter against the reference and against the scalar loops).
#include <gtest/gtest.h>

#include <ATen/Parallel.h>

#include <cmath>
#include <cstdint>

#include "kernels/hash_grid.h"
#include "kernels/hash_grid_cpu.h"
#include "kernels/kernel_test_util.h"

namespace ablenerf {
namespace {

// Uniform points of the unit cube, plus a few on its faces and corners and outside it.
torch::Tensor points(int64_t n, uint64_t seed) {
  auto gen = at::detail::createCPUGenerator(seed);
  auto p = torch::rand({n, 3}, gen, torch::kFloat);
  auto edge = torch::tensor({0.f, 0.f, 0.f, 1.f, 1.f, 1.f, 0.f, 1.f, 0.5f, -0.25f, 1.5f, 0.5f}).view({4, 3});
  return torch::cat({p, edge}).contiguous();
}

torch::Tensor table_for(const HashGridShape& s, uint64_t seed) {
  return test::seeded_randn({s.levels, s.table_size, s.features}, seed).to(torch::kFloat);
}

// One dense level (5^3 vertices in 128 rows) and hashed ones (17^3 ... in 128 rows).
HashGridShape mixed_shape() { return hash_grid_shape(4, 2, 7, 4, 32); }

TEST(HashGrid, ResolutionsGrowGeometrically) {
  const HashGridShape s = hash_grid_shape(16, 2, 19, 16, 2048);
  EXPECT_EQ(s.table_size, 1 << 19);
  const double b = std::exp((std::log(2048.0) - std::log(16.0)) / 15);  // instant-ngp eq. 3: 2^(7/15)
  for (int l = 0; l < 16; ++l)
    EXPECT_EQ(s.resolution[l], static_cast<int>(std::floor(16 * std::pow(b, l) + 1e-9))) << l;
  EXPECT_EQ(s.resolution[0], 16);
  EXPECT_EQ(s.resolution[15], 2048);
  EXPECT_EQ(hash_grid_shape(1, 1, 4, 8, 8).resolution[0], 8);
  EXPECT_THROW(hash_grid_shape(0, 2, 19, 16, 2048), std::invalid_argument);
  EXPECT_THROW(hash_grid_shape(4, 9, 19, 16, 2048), std::invalid_argument);
  EXPECT_THROW(hash_grid_shape(4, 2, 25, 16, 2048), std::invalid_argument);
  EXPECT_THROW(hash_grid_shape(4, 2, 19, 32, 16), std::invalid_argument);
}

TEST(HashGrid, RowsAreDenseWhereTheyFitAndThePapersHashElsewhere) {
  const HashGridShape s = mixed_shape();  // level 0: 4 cells, 125 vertices <= 128 rows
  ASSERT_EQ(s.resolution[0], 4);
  EXPECT_EQ(hash_grid_row(s, 0, 1, 2, 3), 1u + 5u * (2u + 5u * 3u));
  ASSERT_GT(std::pow(s.resolution[3] + 1, 3), 128);
  const uint32_t x = 7, y = 11, z = 30;
  const uint32_t want = (x ^ (y * 2654435761u) ^ (z * 805459861u)) % 128u;  // uint32 wrap-around, then mod T
  EXPECT_EQ(hash_grid_row(s, 3, x, y, z), want);
  const auto t = [](int64_t v) { return torch::full({1}, v, torch::kLong); };
  EXPECT_EQ(hash_grid_rows_reference(t(x), t(y), t(z), s, 3).item<int64_t>(), int64_t{want});
  EXPECT_EQ(hash_grid_rows_reference(t(1), t(2), t(3), s, 0).item<int64_t>(), 86);
}

// Rows set to a linear function of their vertex's position: the interpolation is that function
// exactly, anywhere in the cube (trilinear interpolation reproduces linear fields).
TEST(HashGrid, ReproducesALinearFieldExactly) {
  const HashGridShape s = hash_grid_shape(1, 1, 7, 4, 4);  // 125 vertices, dense
  auto table = torch::zeros({1, s.table_size, 1});
  const double a[3] = {0.7, -1.3, 2.1}, c = 0.25;
  const int side = s.resolution[0] + 1;
  for (int z = 0; z < side; ++z)
    for (int y = 0; y < side; ++y)
      for (int x = 0; x < side; ++x)
        table[0][hash_grid_row(s, 0, x, y, z)][0] = (a[0] * x + a[1] * y + a[2] * z) / s.resolution[0] + c;
  const auto p = points(200, 3).clamp(0, 1).contiguous();
  const auto want = (p.to(torch::kDouble) * torch::tensor({a[0], a[1], a[2]}, torch::kDouble)).sum(1) + c;
  const auto got = hash_grid_encode(p, table, s).view({-1}).to(torch::kDouble);
  EXPECT_LT(test::max_abs(got - want), 2e-6);
  EXPECT_LT(test::max_abs(hash_grid_encode_reference(p, table, s).view({-1}).to(torch::kDouble) - want), 2e-6);
}

// At a vertex the encoding is that vertex's row: a table holding each row's index reads it back.
TEST(HashGrid, AVertexReadsItsOwnRow) {
  const HashGridShape s = hash_grid_shape(4, 1, 7, 4, 32);
  auto table = torch::arange(s.table_size, torch::kFloat).view({1, -1, 1}).expand({s.levels, -1, 1}).contiguous();
  for (int l = 0; l < s.levels; ++l) {
    const int res = s.resolution[l];
    const uint32_t v[3] = {1, static_cast<uint32_t>(res / 2), static_cast<uint32_t>(res - 1)};
    auto p = torch::tensor({float(v[0]) / res, float(v[1]) / res, float(v[2]) / res}).view({1, 3});
    const auto out = hash_grid_encode(p, table, s);
    EXPECT_FLOAT_EQ(out[0][l][0].item<float>(), static_cast<float>(hash_grid_row(s, l, v[0], v[1], v[2]))) << l;
  }
}

TEST(HashGrid, CpuLoopsMatchTheReference) {
  const HashGridShape s = mixed_shape();
  const auto p = points(500, 5);
  const auto table = table_for(s, 6);
  const auto g = test::seeded_randn({p.size(0), s.levels, s.features}, 7).to(torch::kFloat);
  auto t1 = table.clone().requires_grad_(), t2 = table.clone().requires_grad_();
  const auto got = hash_grid_encode(p, t1, s), want = hash_grid_encode_reference(p, t2, s);
  EXPECT_LT(test::max_abs(got - want), 1e-5);
  got.backward(g);
  want.backward(g);
  EXPECT_LT(test::max_abs(t1.grad() - t2.grad()), 1e-4);  // rows summed over ~500 points
  EXPECT_GT(test::max_abs(t1.grad()), 0.1);
}

// The loops are compiled for 2 and 4 floats per row and keep a generic loop for the others
// (kernels/hash_grid_cpu.cpp): every width against the reference, values and the table's gradient.
TEST(HashGrid, EveryRowWidthMatchesTheReference) {
  for (const int features : {1, 2, 3, 4, 8}) {
    const HashGridShape s = hash_grid_shape(4, features, 7, 4, 32);
    const auto p = points(300, 30 + features);
    const auto table = table_for(s, 40 + features);
    const auto g = test::seeded_randn({p.size(0), s.levels, s.features}, 50 + features).to(torch::kFloat);
    auto t1 = table.clone().requires_grad_(), t2 = table.clone().requires_grad_();
    const auto got = hash_grid_encode(p, t1, s), want = hash_grid_encode_reference(p, t2, s);
    EXPECT_LT(test::max_abs(got - want), 1e-5) << features;
    got.backward(g);
    want.backward(g);
    EXPECT_LT(test::max_abs(t1.grad() - t2.grad()), 1e-4) << features;
    EXPECT_GT(test::max_abs(t1.grad()), 0.1) << features;
  }
}

// Each instruction form of the loops (kernels/hash_grid_cpu.h) on raw pointers: point counts that
// fill no, one and several 16-point vectors with a tail, every row width (the vector form takes 2
// floats per row and hands the others to the scalar loops): values and the table's gradient against
// the reference; the scatter the same bits as the scalar loops', the values within an FMA's rounding.
TEST(HashGrid, EveryInstructionFormMatchesTheReferenceAndTheScalarLoops) {
  std::vector<CpuVectorForm> forms;
  for (const auto f : {CpuVectorForm::Avx512, CpuVectorForm::Scalar})
    if (cpu_vector_form_available(f)) forms.push_back(f);
  ASSERT_EQ(forms.back(), CpuVectorForm::Scalar);
  EXPECT_TRUE(cpu_vector_form_available(cpu_best_vector_form()));
  int checked = 0;
  for (const int features : {2, 1, 4}) {
    const HashGridShape s = hash_grid_shape(4, features, 7, 4, 32);
    for (const int64_t n : {1, 15, 16, 17, 504}) {
      const auto p = points(n - 4 > 0 ? n - 4 : 0, 60 + n).slice(0, 0, n).contiguous();
      ASSERT_EQ(p.size(0), n);
      const auto table = table_for(s, 70 + features);
      const auto g = test::seeded_randn({n, s.levels, s.features}, 80 + n).to(torch::kFloat);
      auto t = table.clone().requires_grad_();
      const auto want = hash_grid_encode_reference(p, t, s);
      want.backward(g);
      std::vector<torch::Tensor> outs, grads;
      for (const auto form : forms) {
        auto out = torch::full({n, s.levels, s.features}, std::nanf(""));
        auto grad = torch::zeros_like(table);
        hash_grid_forward_cpu_in(form, p.data_ptr<float>(), n, table.data_ptr<float>(), s, nullptr,
                                 out.data_ptr<float>());
        hash_grid_backward_cpu_in(form, p.data_ptr<float>(), n, g.data_ptr<float>(), s, nullptr,
                                  grad.data_ptr<float>());
        EXPECT_LT(test::max_abs(out - want), 1e-5) << features << " " << n;
        EXPECT_LT(test::max_abs(grad - t.grad()), 1e-4) << features << " " << n;
        outs.push_back(out);
        grads.push_back(grad);
        ++checked;
        // The vector form's two ways of reading the rows: the same bits.
        if (form != CpuVectorForm::Avx512) continue;
        for (const auto reads : {HashGridReads::Loads, HashGridReads::Gathers}) {
          auto other = torch::full_like(out, std::nanf(""));
          hash_grid_forward_cpu_in(form, p.data_ptr<float>(), n, table.data_ptr<float>(), s, nullptr,
                                   other.data_ptr<float>(), reads);
          EXPECT_TRUE(torch::equal(other, out)) << features << " " << n << " " << static_cast<int>(reads);
        }
      }
      for (size_t i = 1; i < forms.size(); ++i) {
        EXPECT_LT(test::max_abs(outs[i] - outs[0]), 1e-6) << features << " " << n;
        EXPECT_TRUE(torch::equal(grads[i], grads[0])) << features << " " << n;
      }
    }
  }
  EXPECT_GE(checked, 15);
}

// Per-point, per-level scales (the front end's anti-aliasing weights) inside the loops: in every
// form, the output and the table's gradient the same bits as the loops without scales followed by
// a separate product of the output and of its gradient (what hash_grid_encode does for scales that
// take a gradient), and, through hash_grid_encode, the positions' gradient too; point counts with a
// 16-point tail, and zero scales (a point outside the cube).
TEST(HashGrid, ScalesInsideTheLoopsAreTheSeparateProductsBits) {
  const HashGridShape s = mixed_shape();
  for (const auto& [form, reads] : {std::pair{CpuVectorForm::Avx512, HashGridReads::Loads},
                                    std::pair{CpuVectorForm::Avx512, HashGridReads::Gathers},
                                    std::pair{CpuVectorForm::Scalar, HashGridReads::Loads}}) {
    if (!cpu_vector_form_available(form)) continue;
    for (const int64_t n : {7, 37}) {
      const auto p = points(n - 4, 100 + n);
      auto scales = torch::rand({n, s.levels}, at::detail::createCPUGenerator(101 + n));
      scales[3].zero_();
      const auto table = table_for(s, 102);
      const auto g = test::seeded_randn({n, s.levels, s.features}, 103 + n).to(torch::kFloat);
      auto plain = torch::empty({n, s.levels, s.features}), fused = torch::empty_like(plain);
      hash_grid_forward_cpu_in(form, p.data_ptr<float>(), n, table.data_ptr<float>(), s, nullptr,
                               plain.data_ptr<float>(), reads);
      hash_grid_forward_cpu_in(form, p.data_ptr<float>(), n, table.data_ptr<float>(), s, scales.data_ptr<float>(),
                               fused.data_ptr<float>(), reads);
      EXPECT_TRUE(torch::equal(fused, plain * scales.unsqueeze(-1))) << n;
      auto grad_plain = torch::zeros_like(table), grad_fused = torch::zeros_like(table);
      const auto g_scaled = (g * scales.unsqueeze(-1)).contiguous();
      hash_grid_backward_cpu_in(form, p.data_ptr<float>(), n, g_scaled.data_ptr<float>(), s, nullptr,
                                grad_plain.data_ptr<float>());
      hash_grid_backward_cpu_in(form, p.data_ptr<float>(), n, g.data_ptr<float>(), s, scales.data_ptr<float>(),
                                grad_fused.data_ptr<float>());
      EXPECT_TRUE(torch::equal(grad_fused, grad_plain)) << n;
      EXPECT_GT(test::max_abs(grad_fused), 0.1);
    }
  }
  // Through the wrapper: the fused scales against scales that take a gradient (a separate product),
  // values, the table's and the positions' gradients.
  const int64_t n = 300;
  const auto p = (torch::rand({n, 3}, at::detail::createCPUGenerator(110)) * 0.9 + 0.05).contiguous();
  const auto scales = torch::rand({n, s.levels}, at::detail::createCPUGenerator(111));
  const auto g = test::seeded_randn({n, s.levels, s.features}, 112).to(torch::kFloat);
  auto t1 = table_for(s, 113).requires_grad_(), t2 = t1.detach().clone().requires_grad_();
  auto p1 = p.clone().requires_grad_(), p2 = p.clone().requires_grad_();
  auto sc2 = scales.clone().requires_grad_();
  const auto a = hash_grid_encode(p1, t1, s, nullptr, scales), b = hash_grid_encode(p2, t2, s, nullptr, sc2);
  EXPECT_TRUE(torch::equal(a, b));
  a.backward(g);
  b.backward(g);
  EXPECT_TRUE(torch::equal(t1.grad(), t2.grad()));
  EXPECT_TRUE(torch::equal(p1.grad(), p2.grad()));
  EXPECT_GT(test::max_abs(p1.grad()), 0.1);
  test::expect_error_naming([&] { hash_grid_encode(p, t1, s, nullptr, scales.slice(1, 0, 2)); }, "scales");
  test::expect_error_naming([&] { hash_grid_encode(p, t1, s, nullptr, scales.to(torch::kDouble)); }, "scales");
}

// A NaN coordinate counts as 0 in every form (hash_grid_cell), not as a stray row.
TEST(HashGrid, EveryInstructionFormReadsANaNCoordinateAsZero) {
  const HashGridShape s = mixed_shape();
  auto p = points(28, 90);  // 32 points: two full vectors
  auto q = p.clone();
  const float nan = std::nanf("");
  for (const int64_t i : {0, 7, 19, 31}) {
    p[i][i % 3] = nan;
    q[i][i % 3] = 0.f;
  }
  const auto table = table_for(s, 91);
  for (const auto& [form, reads] : {std::pair{CpuVectorForm::Avx512, HashGridReads::Loads},
                                    std::pair{CpuVectorForm::Avx512, HashGridReads::Gathers},
                                    std::pair{CpuVectorForm::Scalar, HashGridReads::Loads}}) {
    if (!cpu_vector_form_available(form)) continue;
    auto a = torch::empty({32, s.levels, s.features}), b = torch::empty({32, s.levels, s.features});
    hash_grid_forward_cpu_in(form, p.data_ptr<float>(), 32, table.data_ptr<float>(), s, nullptr, a.data_ptr<float>(),
                             reads);
    hash_grid_forward_cpu_in(form, q.data_ptr<float>(), 32, table.data_ptr<float>(), s, nullptr, b.data_ptr<float>(),
                             reads);
    EXPECT_TRUE(torch::equal(a, b));
  }
}

// The encoding is linear in the table, so central differences on it are exact up to rounding.
TEST(HashGrid, ReferenceGradientMatchesFiniteDifferences) {
  const HashGridShape s = hash_grid_shape(2, 2, 4, 2, 5);  // 27 vertices in 16 rows: level 0 hashed too
  const auto p = points(20, 9).to(torch::kDouble);
  const auto table = test::seeded_randn({s.levels, s.table_size, s.features}, 10);
  const auto g = test::seeded_randn({p.size(0), s.levels, s.features}, 11);
  const test::ScalarFunction f = [&](const std::vector<torch::Tensor>& in) {
    return (hash_grid_encode_reference(p, in[0], s) * g).sum();
  };
  const auto numeric = test::numeric_gradient(f, {table}, 0);
  auto t = table.clone().requires_grad_();
  f({t}).backward();
  EXPECT_LT(test::max_abs(t.grad() - numeric), 1e-7);
  EXPECT_GT(test::max_abs(numeric), 0.1);
}

// The positions' gradient (camera refinement): the loops against the reference's autograd, both
// against central differences of the encoding in the positions (points kept away from the cells'
// faces, where the encoding has a kink), and nothing computed when the positions need none.
TEST(HashGrid, PositionGradientMatchesTheReferenceAndFiniteDifferences) {
  const HashGridShape s = mixed_shape();
  auto gen = at::detail::createCPUGenerator(21);
  // Inside the cube, plus two points outside it (their clamped axes get no gradient).
  auto p = torch::cat({torch::rand({300, 3}, gen, torch::kFloat) * 0.9 + 0.05,
                       torch::tensor({-0.2f, 0.5f, 0.5f, 0.3f, 1.4f, 0.6f}).view({2, 3})})
               .contiguous();
  const auto table = table_for(s, 22);
  const auto g = test::seeded_randn({p.size(0), s.levels, s.features}, 23).to(torch::kFloat);
  auto p1 = p.clone().requires_grad_(), p2 = p.clone().requires_grad_();
  hash_grid_encode(p1, table, s).backward(g);
  hash_grid_encode_reference(p2, table, s).backward(g);
  const auto got = p1.grad(), want = p2.grad();
  EXPECT_LT(test::max_abs(got - want), 2e-3 * test::max_abs(want));
  EXPECT_GT(test::max_abs(want), 1.0);
  EXPECT_EQ(got[300][0].item<float>(), 0.f);  // x = -0.2: clamped
  EXPECT_EQ(got[301][1].item<float>(), 0.f);  // y = 1.4: clamped
  EXPECT_NE(got[300][1].item<float>(), 0.f);

  // Central differences in float64 of the interpolation itself (the reference's arithmetic in
  // double: cells from the float positions, fractions in double), on points whose step stays in
  // its cell at every level.
  const double h = 1e-4;
  const auto pd = p.to(torch::kDouble), td = table.to(torch::kDouble), gd = g.to(torch::kDouble);
  const auto encode = [&](const torch::Tensor& q) { return (hash_grid_encode_reference(q, td, s) * gd).sum(); };
  int checked = 0;
  for (int64_t i = 0; i < 40; ++i) {
    for (int d = 0; d < 3; ++d) {
      const double x = pd[i][d].item<double>();
      bool inside_cell = true;
      for (int l = 0; l < s.levels; ++l) {
        const double q = x * s.resolution[l];
        inside_cell = inside_cell && std::floor(q - 2 * h * s.resolution[l]) == std::floor(q + 2 * h * s.resolution[l]);
      }
      if (!inside_cell) continue;
      auto plus = pd.clone(), minus = pd.clone();
      plus[i][d] += h;
      minus[i][d] -= h;
      const double numeric = (encode(plus).item<double>() - encode(minus).item<double>()) / (2 * h);
      EXPECT_NEAR(got[i][d].item<float>(), numeric, 1e-2 * std::max(1.0, std::abs(numeric))) << i << "," << d;
      ++checked;
    }
  }
  EXPECT_GT(checked, 40);
}

// The loops' scatter gives the same bits with one thread and with several (levels to threads).
TEST(HashGrid, GradientIsTheSameOnAnyThreadCount) {
  const HashGridShape s = mixed_shape();
  const auto p = points(3000, 12);
  const auto table = table_for(s, 13);
  const auto g = test::seeded_randn({p.size(0), s.levels, s.features}, 14).to(torch::kFloat);
  const int before = at::get_num_threads();
  std::vector<torch::Tensor> grads;
  for (int threads : {1, 4}) {
    at::set_num_threads(threads);
    auto t = table.clone().requires_grad_();
    hash_grid_encode(p, t, s).backward(g);
    grads.push_back(t.grad());
  }
  at::set_num_threads(before);
  EXPECT_TRUE(torch::equal(grads[0], grads[1]));
}

TEST(HashGrid, BadInputsAreRefusedNamingTheArgument) {
  const HashGridShape s = mixed_shape();
  const auto p = points(8, 1);
  const auto table = table_for(s, 2);
  test::expect_error_naming([&] { hash_grid_encode(p.to(torch::kDouble), table, s); }, "positions");
  test::expect_error_naming([&] { hash_grid_encode(p.view({-1}), table, s); }, "positions");
  test::expect_error_naming([&] { hash_grid_encode(p, table.slice(1, 0, 64), s); }, "table");
  test::expect_error_naming([&] { hash_grid_encode(p, table.transpose(0, 1).contiguous().transpose(0, 1), s); },
                            "table");
}

}  // namespace
}  // namespace ablenerf
