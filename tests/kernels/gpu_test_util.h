#pragma once
// Shared by the CUDA kernels' tests (test_gpu): the skip when no device is present, inputs drawn
// on the CPU with a seeded generator (the same numbers on every machine), and the error measure
// (expect_error_naming comes from kernel_test_util.h, shared with the CPU tests).
#include <gtest/gtest.h>
#include <torch/torch.h>

#include "kernels/kernel_test_util.h"

#include <string>
#include <vector>

// Every test of test_gpu starts with this: without a CUDA device there is nothing to compare.
#define ABLENERF_REQUIRE_CUDA()                                         \
  do {                                                                  \
    if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device"; \
  } while (0)

namespace ablenerf::test {

// Normal numbers * scale + offset, drawn in float64 on the CPU, then given dtype on the GPU.
inline torch::Tensor cuda_randn(std::vector<int64_t> sizes, uint64_t seed, torch::ScalarType dtype, double scale = 1,
                                double offset = 0) {
  auto gen = at::detail::createCPUGenerator(seed);
  return (torch::randn(sizes, gen, torch::kDouble) * scale + offset).to(torch::kCUDA, dtype);
}

// max |got - want| over max(1, max |want|), in float64: a relative error for large values, an
// absolute one for values around 1 and below.
inline double scaled_error(const torch::Tensor& got, const torch::Tensor& want) {
  const auto g = got.to(torch::kCPU, torch::kDouble), w = want.to(torch::kCPU, torch::kDouble);
  EXPECT_EQ(g.sizes(), w.sizes());
  const double scale = std::max(1.0, w.abs().max().item<double>());
  return (g - w).abs().max().item<double>() / scale;
}

}  // namespace ablenerf::test
