#pragma once
// The multiresolution hash grid's layout and lookups (instant-ngp: Mueller et al. 2022, "Instant
// Neural Graphics Primitives with a Multiresolution Hash Encoding", section 3), shared by the CPU
// loops (hash_grid_cpu.cpp), the CUDA kernels (hash_grid_cuda.cu) and the plain LibTorch reference
// (hash_grid.cpp), so that all three address the table identically. Plain C++: no LibTorch, no
// CUDA headers (nvcc and g++ both compile it).
//
// Level l has resolution[l] cells per side over the unit cube, so (resolution[l] + 1)^3 vertices.
// Its rows live in table[l] (table_size rows of `features` floats). A level whose vertices fit in
// its rows is indexed densely (x + side * (y + side * z)); a finer one through the paper's spatial
// hash, (x * 1 XOR y * 2654435761 XOR z * 805459861) mod table_size, in 32-bit arithmetic. A point's
// features at a level are the trilinear interpolation of its cell's 8 vertex rows.
#include <cmath>
#include <cstdint>

#ifdef __CUDACC__
#define ABLENERF_HOST_DEVICE __host__ __device__
#else
#define ABLENERF_HOST_DEVICE
#endif

namespace ablenerf {

constexpr int kHashGridMaxLevels = 32;
constexpr int kHashGridMaxFeatures = 8;  // floats per row

struct HashGridShape {
  int levels = 0;
  int features = 0;                         // floats per row
  int64_t table_size = 0;                   // rows per level: a power of two, at most 2^24
  int resolution[kHashGridMaxLevels] = {};  // cells per side of each level, >= 1
};

constexpr uint32_t kHashPrimeY = 2654435761u;
constexpr uint32_t kHashPrimeZ = 805459861u;

// Whether `level`'s vertices fit in its rows, so that it is indexed densely rather than hashed.
ABLENERF_HOST_DEVICE inline bool hash_grid_level_is_dense(const HashGridShape& s, int level) {
  const uint64_t side = static_cast<uint64_t>(s.resolution[level]) + 1;
  return side * side * side <= static_cast<uint64_t>(s.table_size);
}

// The rows of `level` a lookup can reach: its vertices when dense, every row when hashed. A dense
// level's other rows are never read or written.
ABLENERF_HOST_DEVICE inline int64_t hash_grid_level_rows(const HashGridShape& s, int level) {
  const int64_t side = int64_t{s.resolution[level]} + 1;
  return hash_grid_level_is_dense(s, level) ? side * side * side : s.table_size;
}

// The row of vertex (x, y, z) at `level`.
ABLENERF_HOST_DEVICE inline uint32_t hash_grid_row(const HashGridShape& s, int level, uint32_t x, uint32_t y,
                                                   uint32_t z) {
  const uint32_t side = static_cast<uint32_t>(s.resolution[level]) + 1;
  if (hash_grid_level_is_dense(s, level)) return x + side * (y + side * z);
  return (x ^ (y * kHashPrimeY) ^ (z * kHashPrimeZ)) & static_cast<uint32_t>(s.table_size - 1);
}

// The cell along one axis and the position inside it, for a coordinate p of the unit interval
// (clamped to it; NaN counts as 0) at `res` cells: cell in [0, res - 1], frac in [0, 1].
ABLENERF_HOST_DEVICE inline void hash_grid_cell(float p, int res, uint32_t& cell, float& frac) {
  const float q = (p >= 0.f ? (p <= 1.f ? p : 1.f) : 0.f) * static_cast<float>(res);
  int c = static_cast<int>(floorf(q));
  if (c > res - 1) c = res - 1;
  cell = static_cast<uint32_t>(c);
  frac = q - static_cast<float>(c);
}

// Calls fn(row, weight) for the 8 vertices of the cell holding point p (3 floats) at `level`, with
// the trilinear weights (they sum to 1). Vertex k has offset bit d of k along axis d.
template <class Fn>
ABLENERF_HOST_DEVICE inline void hash_grid_corners(const HashGridShape& s, int level, const float* p, Fn&& fn) {
  uint32_t c[3];
  float f[3];
  for (int d = 0; d < 3; ++d) hash_grid_cell(p[d], s.resolution[level], c[d], f[d]);
  for (int k = 0; k < 8; ++k) {
    float w = 1.f;
    uint32_t v[3];
    for (int d = 0; d < 3; ++d) {
      const uint32_t bit = (k >> d) & 1u;
      v[d] = c[d] + bit;
      w *= bit ? f[d] : 1.f - f[d];
    }
    fn(hash_grid_row(s, level, v[0], v[1], v[2]), w);
  }
}

// As hash_grid_corners, also passing each weight's derivative with respect to the point's three
// coordinates, fn(row, weight, dweight[3]): along an axis where the coordinate lies outside [0, 1]
// (or is NaN) the derivative is 0, as the clamp's; inside, d frac / d p = resolution.
template <class Fn>
ABLENERF_HOST_DEVICE inline void hash_grid_corners_with_gradient(const HashGridShape& s, int level, const float* p,
                                                                 Fn&& fn) {
  uint32_t c[3];
  float f[3], slope[3];
  for (int d = 0; d < 3; ++d) {
    hash_grid_cell(p[d], s.resolution[level], c[d], f[d]);
    slope[d] = (p[d] >= 0.f && p[d] <= 1.f) ? static_cast<float>(s.resolution[level]) : 0.f;
  }
  for (int k = 0; k < 8; ++k) {
    uint32_t v[3];
    float a[3], sign[3];
    for (int d = 0; d < 3; ++d) {
      const uint32_t bit = (k >> d) & 1u;
      v[d] = c[d] + bit;
      a[d] = bit ? f[d] : 1.f - f[d];
      sign[d] = bit ? 1.f : -1.f;
    }
    const float dw[3] = {sign[0] * slope[0] * a[1] * a[2], sign[1] * slope[1] * a[0] * a[2],
                         sign[2] * slope[2] * a[0] * a[1]};
    fn(hash_grid_row(s, level, v[0], v[1], v[2]), a[0] * a[1] * a[2], dw);
  }
}

}  // namespace ablenerf
