// The hash-grid encoding on the GPU (hash_grid_launch.h): one thread per (point, level), threads of
// one point side by side so that their outputs are adjacent in memory.
#include "kernels/hash_grid_launch.h"

namespace ablenerf {

namespace {

constexpr int kThreads = 256;
constexpr int kMaxFeatures = 8;

__global__ void __launch_bounds__(kThreads)
    forward_kernel(const float* __restrict__ positions, int64_t n, const float* __restrict__ table, HashGridShape s,
                   float* __restrict__ out) {
  const int64_t i = static_cast<int64_t>(blockIdx.x) * kThreads + threadIdx.x;
  if (i >= n * s.levels) return;
  const int64_t point = i / s.levels;
  const int level = static_cast<int>(i - point * s.levels);
  float p[3] = {positions[3 * point], positions[3 * point + 1], positions[3 * point + 2]};
  float acc[kMaxFeatures] = {};
  const float* rows = table + static_cast<int64_t>(level) * s.table_size * s.features;
  hash_grid_corners(s, level, p, [&](uint32_t row, float w) {
    const float* r = rows + static_cast<int64_t>(row) * s.features;
    for (int f = 0; f < s.features; ++f) acc[f] += w * __ldg(r + f);
  });
  float* o = out + i * s.features;
  for (int f = 0; f < s.features; ++f) o[f] = acc[f];
}

__global__ void __launch_bounds__(kThreads)
    backward_kernel(const float* __restrict__ positions, int64_t n, const float* __restrict__ grad_out, HashGridShape s,
                    float* __restrict__ grad_table) {
  const int64_t i = static_cast<int64_t>(blockIdx.x) * kThreads + threadIdx.x;
  if (i >= n * s.levels) return;
  const int64_t point = i / s.levels;
  const int level = static_cast<int>(i - point * s.levels);
  float p[3] = {positions[3 * point], positions[3 * point + 1], positions[3 * point + 2]};
  float g[kMaxFeatures];
  for (int f = 0; f < s.features; ++f) g[f] = grad_out[i * s.features + f];
  float* rows = grad_table + static_cast<int64_t>(level) * s.table_size * s.features;
  hash_grid_corners(s, level, p, [&](uint32_t row, float w) {
    float* r = rows + static_cast<int64_t>(row) * s.features;
    for (int f = 0; f < s.features; ++f) atomicAdd(r + f, w * g[f]);
  });
}

__global__ void __launch_bounds__(kThreads)
    backward_positions_kernel(const float* __restrict__ positions, int64_t n, const float* __restrict__ grad_out,
                              const float* __restrict__ table, HashGridShape s, float* __restrict__ grad_positions) {
  const int64_t i = static_cast<int64_t>(blockIdx.x) * kThreads + threadIdx.x;
  if (i >= n) return;
  float p[3] = {positions[3 * i], positions[3 * i + 1], positions[3 * i + 2]};
  float acc[3] = {0.f, 0.f, 0.f};
  for (int level = 0; level < s.levels; ++level) {
    float g[kMaxFeatures];
    for (int f = 0; f < s.features; ++f) g[f] = grad_out[(i * s.levels + level) * s.features + f];
    const float* rows = table + static_cast<int64_t>(level) * s.table_size * s.features;
    hash_grid_corners_with_gradient(s, level, p, [&](uint32_t row, float, const float* dw) {
      const float* r = rows + static_cast<int64_t>(row) * s.features;
      float dot = 0.f;
      for (int f = 0; f < s.features; ++f) dot += g[f] * __ldg(r + f);
      for (int d = 0; d < 3; ++d) acc[d] += dot * dw[d];
    });
  }
  for (int d = 0; d < 3; ++d) grad_positions[3 * i + d] = acc[d];
}

unsigned blocks_for(int64_t threads) { return static_cast<unsigned>((threads + kThreads - 1) / kThreads); }

}  // namespace

cudaError_t launch_hash_grid_forward(const float* positions, int64_t n, const float* table, const HashGridShape& s,
                                     float* out, cudaStream_t stream) {
  if (n == 0) return cudaSuccess;
  forward_kernel<<<blocks_for(n * s.levels), kThreads, 0, stream>>>(positions, n, table, s, out);
  return cudaGetLastError();
}

cudaError_t launch_hash_grid_backward(const float* positions, int64_t n, const float* grad_out, const HashGridShape& s,
                                      float* grad_table, cudaStream_t stream) {
  if (n == 0) return cudaSuccess;
  backward_kernel<<<blocks_for(n * s.levels), kThreads, 0, stream>>>(positions, n, grad_out, s, grad_table);
  return cudaGetLastError();
}

cudaError_t launch_hash_grid_backward_positions(const float* positions, int64_t n, const float* grad_out,
                                                const float* table, const HashGridShape& s, float* grad_positions,
                                                cudaStream_t stream) {
  if (n == 0) return cudaSuccess;
  backward_positions_kernel<<<blocks_for(n), kThreads, 0, stream>>>(positions, n, grad_out, table, s, grad_positions);
  return cudaGetLastError();
}

}  // namespace ablenerf
