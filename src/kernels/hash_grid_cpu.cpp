#include "kernels/hash_grid_cpu.h"

#include <ATen/Parallel.h>

namespace ablenerf {

namespace {
constexpr int64_t kPointsPerTask = 1024;
}  // namespace

void hash_grid_forward_cpu(const float* positions, int64_t n, const float* table, const HashGridShape& s, float* out) {
  const int64_t levels = s.levels, features = s.features, rows = s.table_size;
  at::parallel_for(0, n, kPointsPerTask, [&](int64_t lo, int64_t hi) {
    for (int64_t i = lo; i < hi; ++i) {
      const float* p = positions + 3 * i;
      for (int l = 0; l < levels; ++l) {
        float* o = out + (i * levels + l) * features;
        for (int64_t f = 0; f < features; ++f) o[f] = 0.f;
        const float* level_rows = table + l * rows * features;
        hash_grid_corners(s, l, p, [&](uint32_t row, float w) {
          const float* r = level_rows + int64_t{row} * features;
          for (int64_t f = 0; f < features; ++f) o[f] += w * r[f];
        });
      }
    }
  });
}

void hash_grid_backward_cpu(const float* positions, int64_t n, const float* grad_out, const HashGridShape& s,
                            float* grad_table) {
  const int64_t levels = s.levels, features = s.features, rows = s.table_size;
  at::parallel_for(0, levels, 1, [&](int64_t lo, int64_t hi) {
    for (int64_t l = lo; l < hi; ++l) {
      float* level_rows = grad_table + l * rows * features;
      for (int64_t i = 0; i < n; ++i) {
        const float* g = grad_out + (i * levels + l) * features;
        hash_grid_corners(s, static_cast<int>(l), positions + 3 * i, [&](uint32_t row, float w) {
          float* r = level_rows + int64_t{row} * features;
          for (int64_t f = 0; f < features; ++f) r[f] += w * g[f];
        });
      }
    }
  });
}

void hash_grid_backward_positions_cpu(const float* positions, int64_t n, const float* grad_out, const float* table,
                                      const HashGridShape& s, float* grad_positions) {
  const int64_t levels = s.levels, features = s.features, rows = s.table_size;
  at::parallel_for(0, n, kPointsPerTask, [&](int64_t lo, int64_t hi) {
    for (int64_t i = lo; i < hi; ++i) {
      float acc[3] = {0.f, 0.f, 0.f};
      for (int l = 0; l < levels; ++l) {
        const float* g = grad_out + (i * levels + l) * features;
        const float* level_rows = table + l * rows * features;
        hash_grid_corners_with_gradient(s, l, positions + 3 * i, [&](uint32_t row, float, const float* dw) {
          const float* r = level_rows + int64_t{row} * features;
          float dot = 0.f;
          for (int64_t f = 0; f < features; ++f) dot += g[f] * r[f];
          for (int d = 0; d < 3; ++d) acc[d] += dot * dw[d];
        });
      }
      for (int d = 0; d < 3; ++d) grad_positions[3 * i + d] = acc[d];
    }
  });
}

}  // namespace ablenerf
