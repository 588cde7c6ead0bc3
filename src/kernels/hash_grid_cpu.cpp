#include "kernels/hash_grid_cpu.h"

#include <ATen/Parallel.h>

#include <type_traits>

namespace ablenerf {

namespace {

constexpr int64_t kPointsPerTask = 1024;

// One level's features for points [lo, hi), `F` floats per row known at compile time (the
// presets' 2 and the common 4: the row's loads and sums unroll), or F = 0 for any count (`features`).
// Level by level rather than point by point: a hashed level's rows (2^16 x 2 floats = 512 KiB at
// the capture preset) stay in the core's L2 cache while every point reads them, where a point
// reading all levels in turn sweeps the whole table (4 MiB) through it (docs/benchmarks/history.md,
// "Hash-grid loops level by level").
template <int F>
void forward_level(const float* positions, int64_t lo, int64_t hi, const float* level_rows, const HashGridShape& s,
                   int level, int64_t features, float* out) {
  const int64_t nf = F > 0 ? F : features;
  for (int64_t i = lo; i < hi; ++i) {
    float acc[F > 0 ? F : kHashGridMaxFeatures] = {};
    hash_grid_corners(s, level, positions + 3 * i, [&](uint32_t row, float w) {
      const float* r = level_rows + int64_t{row} * nf;
      for (int64_t f = 0; f < nf; ++f) acc[f] += w * r[f];
    });
    float* o = out + (i * s.levels + level) * nf;
    for (int64_t f = 0; f < nf; ++f) o[f] = acc[f];
  }
}

// The scatter of one level's output gradient over all n points, in point order.
template <int F>
void backward_level(const float* positions, int64_t n, const float* grad_out, const HashGridShape& s, int level,
                    int64_t features, float* level_rows) {
  const int64_t nf = F > 0 ? F : features;
  for (int64_t i = 0; i < n; ++i) {
    float g[F > 0 ? F : kHashGridMaxFeatures];
    for (int64_t f = 0; f < nf; ++f) g[f] = grad_out[(i * s.levels + level) * nf + f];
    hash_grid_corners(s, level, positions + 3 * i, [&](uint32_t row, float w) {
      float* r = level_rows + int64_t{row} * nf;
      for (int64_t f = 0; f < nf; ++f) r[f] += w * g[f];
    });
  }
}

// Calls body(std::integral_constant<int, F>) with F the compile-time feature count where there is one, else 0.
template <class Body>
void with_features(int64_t features, Body&& body) {
  switch (features) {
    case 2: body(std::integral_constant<int, 2>()); break;
    case 4: body(std::integral_constant<int, 4>()); break;
    default: body(std::integral_constant<int, 0>());
  }
}

}  // namespace

void hash_grid_forward_cpu(const float* positions, int64_t n, const float* table, const HashGridShape& s, float* out) {
  const int64_t features = s.features, rows = s.table_size;
  with_features(features, [&](auto f) {
    constexpr int F = decltype(f)::value;
    at::parallel_for(0, n, kPointsPerTask, [&](int64_t lo, int64_t hi) {
      for (int l = 0; l < s.levels; ++l)
        forward_level<F>(positions, lo, hi, table + l * rows * features, s, l, features, out);
    });
  });
}

void hash_grid_backward_cpu(const float* positions, int64_t n, const float* grad_out, const HashGridShape& s,
                            float* grad_table) {
  const int64_t features = s.features, rows = s.table_size;
  with_features(features, [&](auto f) {
    constexpr int F = decltype(f)::value;
    at::parallel_for(0, s.levels, 1, [&](int64_t lo, int64_t hi) {
      for (int64_t l = lo; l < hi; ++l)
        backward_level<F>(positions, n, grad_out, s, static_cast<int>(l), features, grad_table + l * rows * features);
    });
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
