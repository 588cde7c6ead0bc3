// The CUDA hash-grid encoding (kernels/hash_grid.h) against its plain LibTorch reference on the GPU:
// values, the table's gradient and the positions' (atomic adds: equal to float rounding, not bit for bit), with a
// dense level and hashed ones, at the model's shape, an empty batch, and the input checks.
#include <gtest/gtest.h>

#include "kernels/gpu_test_util.h"
#include "kernels/hash_grid.h"

namespace ablenerf {
namespace {

void compare(const HashGridShape& s, int64_t n, uint64_t seed) {
  auto gen = at::detail::createCPUGenerator(seed);
  // Points slightly beyond the cube too (clamped alike by both).
  const auto p = (torch::rand({n, 3}, gen, torch::kFloat) * 1.1 - 0.05).to(torch::kCUDA).contiguous();
  const auto table = test::cuda_randn({s.levels, s.table_size, s.features}, seed + 1, torch::kFloat);
  const auto g = test::cuda_randn({n, s.levels, s.features}, seed + 2, torch::kFloat);
  auto t1 = table.clone().requires_grad_(), t2 = table.clone().requires_grad_();
  auto p1 = p.clone().requires_grad_(), p2 = p.clone().requires_grad_();
  const auto got = hash_grid_encode(p1, t1, s), want = hash_grid_encode_reference(p2, t2, s);
  EXPECT_LT(test::scaled_error(got, want), 1e-5) << "values, n " << n;
  got.backward(g);
  want.backward(g);
  EXPECT_LT(test::scaled_error(t1.grad(), t2.grad()), 1e-5) << "table gradient, n " << n;
  EXPECT_LT(test::scaled_error(p1.grad(), p2.grad()), 1e-4) << "positions' gradient, n " << n;
}

TEST(HashGridGpu, MatchesReferenceDenseAndHashedLevels) {
  ABLENERF_REQUIRE_CUDA();
  compare(hash_grid_shape(4, 2, 7, 4, 32), 1000, 1);
  compare(hash_grid_shape(3, 4, 10, 2, 64), 257, 2);
}

TEST(HashGridGpu, MatchesReferenceAtTheModelsShape) {
  ABLENERF_REQUIRE_CUDA();
  compare(hash_grid_shape(16, 2, 19, 16, 2048), 1 << 16, 3);
}

TEST(HashGridGpu, EmptyBatch) {
  ABLENERF_REQUIRE_CUDA();
  const HashGridShape s = hash_grid_shape(2, 2, 6, 2, 8);
  auto table = torch::zeros({2, 64, 2}, torch::TensorOptions().device(torch::kCUDA)).requires_grad_();
  const auto out = hash_grid_encode(torch::zeros({0, 3}, table.options().requires_grad(false)), table, s);
  EXPECT_EQ(out.sizes(), (std::vector<int64_t>{0, 2, 2}));
  out.sum().backward();
  EXPECT_EQ(table.grad().abs().sum().item<float>(), 0.f);
}

TEST(HashGridGpu, RefusesMixedDevices) {
  ABLENERF_REQUIRE_CUDA();
  const HashGridShape s = hash_grid_shape(2, 2, 6, 2, 8);
  const auto table = torch::zeros({2, 64, 2});
  test::expect_error_naming([&] { hash_grid_encode(torch::zeros({4, 3}, torch::kCUDA), table, s); }, "table");
}

}  // namespace
}  // namespace ablenerf
