#include "kernels/hash_grid_cpu.h"

#include <ATen/Parallel.h>

#include <algorithm>
#include <stdexcept>
#include <type_traits>

#include "kernels/cpu_features.h"

#ifdef ABLENERF_HAVE_AVX2_FORM
#include <immintrin.h>
// GCC 12's AVX-512 intrinsics start their results from _mm512_undefined_*(), which it then reports
// as "may be used uninitialized" where they are inlined (GCC bug 105593, fixed in GCC 13).
#if defined(__GNUC__) && !defined(__clang__) && __GNUC__ < 13
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#endif

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
                   int level, int64_t features, const float* scales, float* out) {
  const int64_t nf = F > 0 ? F : features;
  for (int64_t i = lo; i < hi; ++i) {
    float acc[F > 0 ? F : kHashGridMaxFeatures] = {};
    hash_grid_corners(s, level, positions + 3 * i, [&](uint32_t row, float w) {
      const float* r = level_rows + int64_t{row} * nf;
      for (int64_t f = 0; f < nf; ++f) acc[f] += w * r[f];
    });
    float* o = out + (i * s.levels + level) * nf;
    const float scale = scales != nullptr ? scales[i * s.levels + level] : 1.f;
    for (int64_t f = 0; f < nf; ++f) o[f] = acc[f] * scale;
  }
}

// The scatter of one level's output gradient over all n points, in point order.
template <int F>
void backward_level(const float* positions, int64_t n, const float* grad_out, const HashGridShape& s, int level,
                    int64_t features, const float* scales, float* level_rows) {
  const int64_t nf = F > 0 ? F : features;
  for (int64_t i = 0; i < n; ++i) {
    float g[F > 0 ? F : kHashGridMaxFeatures];
    const float scale = scales != nullptr ? scales[i * s.levels + level] : 1.f;
    for (int64_t f = 0; f < nf; ++f) g[f] = grad_out[(i * s.levels + level) * nf + f] * scale;
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

#ifdef ABLENERF_HAVE_AVX2_FORM
// The AVX-512 form for 2 floats per row: 16 points at a time, one vertex of their cells after the
// other: cells, rows and weights in vectors, the rows (8 bytes each) read point by point.
namespace hash_grid_avx512 {

constexpr int kLanes = 16;

// 16 points' cells and positions inside them along the three axes, as hash_grid_cell.
struct Cells {
  __m512i cell[3];
  __m512 frac[3];
};

ABLENERF_TARGET_AVX512 ABLENERF_ALWAYS_INLINE Cells cells_of(const float* p, int res) {
  const __m512i stride = _mm512_setr_epi32(0, 3, 6, 9, 12, 15, 18, 21, 24, 27, 30, 33, 36, 39, 42, 45);
  const __m512 zero = _mm512_setzero_ps(), one = _mm512_set1_ps(1.f), scale = _mm512_set1_ps(static_cast<float>(res));
  const __m512i top = _mm512_set1_epi32(res - 1);
  Cells c;
  for (int d = 0; d < 3; ++d) {
    const __m512 x = _mm512_i32gather_ps(stride, p + d, 4);
    // max(x, 0) is 0 where x is NaN (x86's max returns its second operand then), as hash_grid_cell.
    const __m512 q = _mm512_mul_ps(_mm512_min_ps(_mm512_max_ps(x, zero), one), scale);
    const __m512i cell =
        _mm512_min_epi32(_mm512_cvttps_epi32(_mm512_roundscale_ps(q, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC)), top);
    c.cell[d] = cell;
    c.frac[d] = _mm512_sub_ps(q, _mm512_cvtepi32_ps(cell));
  }
  return c;
}

// The level's addressing (hash_grid_row): dense, or the spatial hash masked to the table.
struct Addressing {
  bool dense;
  uint32_t side, mask;
  Addressing(const HashGridShape& s, int level)
      : dense(hash_grid_level_is_dense(s, level)),
        side(static_cast<uint32_t>(s.resolution[level]) + 1),
        mask(static_cast<uint32_t>(s.table_size - 1)) {}
};

// A level's rows prefetched in order (into L2) before `points` points read (or add to) them at
// random, when their corners are at least as many as the rows' cache lines: the whole level then
// moves into the core's cache at the memory's streaming rate instead of one random miss after
// another. Rendering at the capture preset (bench, in pairs): 29,900-41,000 -> 40,200-57,300 rays/s
// (docs/benchmarks/history.md, "The grid's levels prefetched"). Only a thread's first level waits
// for its rows this way; each next level streams in while the one before is read (LevelStream).
class LevelStream {
 public:
  static constexpr int64_t kLineFloats = 16;

  LevelStream() = default;
  // Level `level`'s rows, to be streamed over `batches` batches of points; nothing when the level's
  // corners are fewer than its lines.
  LevelStream(const float* level_rows, const HashGridShape& s, int level, int64_t points, int64_t batches) {
    const Addressing a(s, level);
    const int64_t rows = a.dense ? int64_t{a.side} * a.side * a.side : s.table_size;
    const int64_t floats = rows * 2;
    if (points * 8 < floats / kLineFloats) return;
    next_ = level_rows;
    end_ = level_rows + floats;
    // A little over the even share, so that the level is in before the last batches (an even
    // ceiling share measured 6% slower training at the capture preset).
    per_batch_ = (floats / kLineFloats + batches) / std::max<int64_t>(batches, 1) + 1;
  }
  // The next share of the lines (one batch's).
  ABLENERF_ALWAYS_INLINE void advance() {
    for (int64_t k = 0; k < per_batch_ && next_ < end_; ++k, next_ += kLineFloats)
      _mm_prefetch(reinterpret_cast<const char*>(next_), _MM_HINT_T1);
  }
  // Every line not yet asked for.
  void finish() {
    for (; next_ < end_; next_ += kLineFloats) _mm_prefetch(reinterpret_cast<const char*>(next_), _MM_HINT_T1);
  }

 private:
  const float* next_ = nullptr;
  const float* end_ = nullptr;
  int64_t per_batch_ = 0;
};

// The stream of level `level` + 1 while `level` is read by `points` points in batches of 16, or none
// after the last level.
inline LevelStream next_level_stream(const float* table, const HashGridShape& s, int level, int64_t points) {
  if (level + 1 >= s.levels) return LevelStream();
  return LevelStream(table + int64_t{level + 1} * s.table_size * 2, s, level + 1, points, points / 16);
}

// A level's rows prefetched all at once: the first level a thread reads.
inline void warm_level(const float* table, const HashGridShape& s, int level, int64_t points) {
  LevelStream(table + int64_t{level} * s.table_size * 2, s, level, points, 1).finish();
}

// The rows and trilinear weights of 16 points' eight vertices (hash_grid_corners' order and
// products): each axis's two row terms and two weights formed once, so that a vertex costs one sum
// (dense level) or two exclusive ors (hashed level) and one product. The terms wrap modulo 2^32
// as hash_grid_row's products do, (c + 1) p = c p + p, so the rows are the same integers.
struct Vertices {
  __m512i term[3][2];
  __m512 weight_xy[4], weight_z[2];
  bool dense;
  __m512i mask;

  ABLENERF_TARGET_AVX512 ABLENERF_ALWAYS_INLINE Vertices(const Cells& c, const Addressing& a) : dense(a.dense) {
    const __m512i one_i = _mm512_set1_epi32(1);
    const __m512 one = _mm512_set1_ps(1.f);
    __m512 w[3][2];
    for (int d = 0; d < 3; ++d) w[d][0] = _mm512_sub_ps(one, c.frac[d]), w[d][1] = c.frac[d];
    for (int k = 0; k < 4; ++k) weight_xy[k] = _mm512_mul_ps(w[0][k & 1], w[1][k >> 1]);
    weight_z[0] = w[2][0], weight_z[1] = w[2][1];
    // Dense: x + side (y + side z); hashed: x ^ y pY ^ z pZ, masked to the table.
    const uint32_t side = a.side;
    const uint32_t factor[3] = {1u, dense ? side : kHashPrimeY, dense ? side * side : kHashPrimeZ};
    for (int d = 0; d < 3; ++d) {
      const __m512i f = _mm512_set1_epi32(static_cast<int>(factor[d]));
      term[d][0] = d == 0 ? c.cell[0] : _mm512_mullo_epi32(c.cell[d], f);
      term[d][1] = _mm512_add_epi32(term[d][0], d == 0 ? one_i : f);
    }
    mask = _mm512_set1_epi32(static_cast<int>(a.mask));
  }
  // Vertex k (bit d of k: the cell's upper corner along axis d).
  ABLENERF_TARGET_AVX512 ABLENERF_ALWAYS_INLINE void at(int k, __m512i& row, __m512& weight) const {
    const int bx = k & 1, by = (k >> 1) & 1, bz = (k >> 2) & 1;
    weight = _mm512_mul_ps(weight_xy[k & 3], weight_z[bz]);
    row = dense ? _mm512_add_epi32(term[0][bx], _mm512_add_epi32(term[1][by], term[2][bz]))
                : _mm512_and_si512(_mm512_xor_si512(_mm512_xor_si512(term[0][bx], term[1][by]), term[2][bz]), mask);
  }
};

// Lanes 0-7 and 8-15 of a weight, each twice: beside the two floats of a row.
ABLENERF_TARGET_AVX512 ABLENERF_ALWAYS_INLINE __m512 pairs_low(__m512 w) {
  return _mm512_permutexvar_ps(_mm512_setr_epi32(0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6, 6, 7, 7), w);
}
ABLENERF_TARGET_AVX512 ABLENERF_ALWAYS_INLINE __m512 pairs_high(__m512 w) {
  return _mm512_permutexvar_ps(_mm512_setr_epi32(8, 8, 9, 9, 10, 10, 11, 11, 12, 12, 13, 13, 14, 14, 15, 15), w);
}

// The 16 points' scales at one level of an (n, levels) array (`levels` floats apart), starting at
// point i.
ABLENERF_TARGET_AVX512 ABLENERF_ALWAYS_INLINE __m512 level_scales(const float* scales, int64_t i, int levels,
                                                                  int level) {
  const __m512i stride = _mm512_mullo_epi32(_mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15),
                                            _mm512_set1_epi32(levels));
  return _mm512_i32gather_ps(stride, scales + i * levels + level, 4);
}

// Points i, ..., i + 7 of an (n, levels, 2) array at one level: 8-byte lanes `levels` apart.
ABLENERF_TARGET_AVX512 ABLENERF_ALWAYS_INLINE __m256i point_stride(int levels) {
  return _mm256_mullo_epi32(_mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7), _mm256_set1_epi32(levels));
}

// The rows and weights of 16 points' vertices as vectors, then each point's eight rows read with
// plain 8-byte loads and summed in vertex order (the scalar loop's order). Against one 64-bit
// gather per 8 points and vertex, 0.85x the time on an AMD Zen 4 core, whose gathers are
// microcoded (docs/benchmarks/history.md, "Kept slice threads, plain loads in the grid's gather").
ABLENERF_TARGET_AVX512 void gather_level(const float* positions, int64_t lo, int64_t hi, const float* level_rows,
                                         const HashGridShape& s, int level, LevelStream next, const float* scales,
                                         float* out) {
  const Addressing a(s, level);
  alignas(64) uint32_t rows[8][kLanes];
  alignas(64) float weights[8][kLanes];
  int64_t i = lo;
  for (; i + kLanes <= hi; i += kLanes) {
    next.advance();
    const Vertices corners(cells_of(positions + 3 * i, s.resolution[level]), a);
    for (int k = 0; k < 8; ++k) {
      __m512i row;
      __m512 w;
      corners.at(k, row, w);
      _mm512_store_si512(rows[k], row);
      _mm512_store_ps(weights[k], w);
    }
    for (int p = 0; p < kLanes; ++p) {
      __m128 acc = _mm_setzero_ps();
      for (int k = 0; k < 8; ++k) {
        const __m128 r =
            _mm_castpd_ps(_mm_load_sd(reinterpret_cast<const double*>(level_rows + int64_t{rows[k][p]} * 2)));
        acc = _mm_fmadd_ps(_mm_set1_ps(weights[k][p]), r, acc);
      }
      if (scales != nullptr) acc = _mm_mul_ps(acc, _mm_set1_ps(scales[(i + p) * s.levels + level]));
      _mm_store_sd(reinterpret_cast<double*>(out + ((i + p) * s.levels + level) * 2), _mm_castps_pd(acc));
    }
  }
  next.finish();
  forward_level<2>(positions, i, hi, level_rows, s, level, 2, scales, out);  // the last < 16 points
}

// The same with the rows read by vector gathers (HashGridReads::Gathers): each vertex's 16 rows
// (8 bytes each) in two 64-bit gathers of 8 points, multiplied by the weights beside them and summed
// in vertex order: the same products and sums as gather_level's, so the same bits.
ABLENERF_TARGET_AVX512 void gather_level_vector(const float* positions, int64_t lo, int64_t hi, const float* level_rows,
                                                const HashGridShape& s, int level, LevelStream next,
                                                const float* scales, float* out) {
  const Addressing a(s, level);
  const auto* rows64 = reinterpret_cast<const long long*>(level_rows);
  const __m256i stride = point_stride(s.levels);
  int64_t i = lo;
  for (; i + kLanes <= hi; i += kLanes) {
    next.advance();
    const Vertices corners(cells_of(positions + 3 * i, s.resolution[level]), a);
    __m512 acc_low = _mm512_setzero_ps(), acc_high = _mm512_setzero_ps();
    for (int k = 0; k < 8; ++k) {
      __m512i row;
      __m512 w;
      corners.at(k, row, w);
      const __m512 r_low = _mm512_castsi512_ps(_mm512_i32gather_epi64(_mm512_castsi512_si256(row), rows64, 8));
      const __m512 r_high = _mm512_castsi512_ps(_mm512_i32gather_epi64(_mm512_extracti64x4_epi64(row, 1), rows64, 8));
      acc_low = _mm512_fmadd_ps(pairs_low(w), r_low, acc_low);
      acc_high = _mm512_fmadd_ps(pairs_high(w), r_high, acc_high);
    }
    if (scales != nullptr) {
      const __m512 sc = level_scales(scales, i, s.levels, level);
      acc_low = _mm512_mul_ps(acc_low, pairs_low(sc));
      acc_high = _mm512_mul_ps(acc_high, pairs_high(sc));
    }
    auto* o = reinterpret_cast<long long*>(out + (i * s.levels + level) * 2);
    _mm512_i32scatter_epi64(o, stride, _mm512_castps_si512(acc_low), 8);
    _mm512_i32scatter_epi64(o + 8 * int64_t{s.levels}, stride, _mm512_castps_si512(acc_high), 8);
  }
  next.finish();
  forward_level<2>(positions, i, hi, level_rows, s, level, 2, scales, out);  // the last < 16 points
}

// The rows and products of 16 points' vertices as vectors, then added to the rows point by point,
// each point's vertices in order: the scalar loop's products and order of sums.
ABLENERF_TARGET_AVX512 void scatter_level(const float* positions, int64_t n, const float* grad_out,
                                          const HashGridShape& s, int level, LevelStream next, const float* scales,
                                          float* level_rows) {
  const Addressing a(s, level);
  const __m256i stride = point_stride(s.levels);
  alignas(64) uint32_t rows[8][kLanes];
  alignas(64) float products[8][2 * kLanes];
  int64_t i = 0;
  for (; i + kLanes <= n; i += kLanes) {
    next.advance();
    const Vertices corners(cells_of(positions + 3 * i, s.resolution[level]), a);
    const auto* g = reinterpret_cast<const long long*>(grad_out + (i * s.levels + level) * 2);
    __m512 g_low = _mm512_castsi512_ps(_mm512_i32gather_epi64(stride, g, 8));
    __m512 g_high = _mm512_castsi512_ps(_mm512_i32gather_epi64(stride, g + 8 * int64_t{s.levels}, 8));
    if (scales != nullptr) {
      // Each point's scale beside its two floats.
      const __m512 sc = level_scales(scales, i, s.levels, level);
      g_low = _mm512_mul_ps(g_low, pairs_low(sc));
      g_high = _mm512_mul_ps(g_high, pairs_high(sc));
    }
    for (int k = 0; k < 8; ++k) {
      __m512i row;
      __m512 w;
      corners.at(k, row, w);
      _mm512_store_si512(rows[k], row);
      _mm512_store_ps(products[k], _mm512_mul_ps(pairs_low(w), g_low));
      _mm512_store_ps(products[k] + kLanes, _mm512_mul_ps(pairs_high(w), g_high));
    }
    for (int p = 0; p < kLanes; ++p) {
      for (int k = 0; k < 8; ++k) {
        float* r = level_rows + int64_t{rows[k][p]} * 2;
        r[0] += products[k][2 * p];
        r[1] += products[k][2 * p + 1];
      }
    }
  }
  next.finish();
  backward_level<2>(positions + 3 * i, n - i, grad_out + i * s.levels * 2, s, level, 2,
                    scales != nullptr ? scales + i * s.levels : nullptr, level_rows);
}

}  // namespace hash_grid_avx512
#endif

// Whether `form` has its own loops for rows of `features` floats (else the scalar loops serve it).
bool vector_loops(CpuVectorForm form, int64_t features) {
#ifdef ABLENERF_HAVE_AVX2_FORM
  return form == CpuVectorForm::Avx512 && features == 2;
#else
  (void)form, (void)features;
  return false;
#endif
}

}  // namespace

HashGridReads hash_grid_best_reads() {
#ifdef ABLENERF_HAVE_AVX2_FORM
  static const HashGridReads best = __builtin_cpu_is("intel") ? HashGridReads::Gathers : HashGridReads::Loads;
  return best;
#else
  return HashGridReads::Loads;
#endif
}

void hash_grid_forward_cpu_in(CpuVectorForm form, const float* positions, int64_t n, const float* table,
                              const HashGridShape& s, const float* scales, float* out, HashGridReads reads) {
  if (!cpu_vector_form_available(form)) throw std::invalid_argument("hash grid: AVX-512 form on a CPU without it");
  const int64_t features = s.features, rows = s.table_size;
  const bool vector = vector_loops(form, features);
  with_features(features, [&](auto f) {
    constexpr int F = decltype(f)::value;
    at::parallel_for(0, n, kPointsPerTask, [&](int64_t lo, int64_t hi) {
      for (int l = 0; l < s.levels; ++l) {
        const float* level_rows = table + l * rows * features;
#ifdef ABLENERF_HAVE_AVX2_FORM
        if (vector) {
          if (l == 0) hash_grid_avx512::warm_level(table, s, l, hi - lo);
          const auto next = hash_grid_avx512::next_level_stream(table, s, l, hi - lo);
          if (reads == HashGridReads::Gathers)
            hash_grid_avx512::gather_level_vector(positions, lo, hi, level_rows, s, l, next, scales, out);
          else
            hash_grid_avx512::gather_level(positions, lo, hi, level_rows, s, l, next, scales, out);
          continue;
        }
#endif
        forward_level<F>(positions, lo, hi, level_rows, s, l, features, scales, out);
      }
    });
  });
}

void hash_grid_backward_level_cpu_in(CpuVectorForm form, const float* positions, int64_t n, const float* grad_out,
                                     const HashGridShape& s, int level, const float* scales, float* level_rows) {
  if (!cpu_vector_form_available(form)) throw std::invalid_argument("hash grid: AVX-512 form on a CPU without it");
#ifdef ABLENERF_HAVE_AVX2_FORM
  if (vector_loops(form, s.features)) {
    hash_grid_avx512::scatter_level(positions, n, grad_out, s, level, hash_grid_avx512::LevelStream(), scales,
                                    level_rows);
    return;
  }
#endif
  with_features(s.features, [&](auto f) {
    backward_level<decltype(f)::value>(positions, n, grad_out, s, level, s.features, scales, level_rows);
  });
}

void hash_grid_backward_cpu_in(CpuVectorForm form, const float* positions, int64_t n, const float* grad_out,
                               const HashGridShape& s, const float* scales, float* grad_table) {
  if (!cpu_vector_form_available(form)) throw std::invalid_argument("hash grid: AVX-512 form on a CPU without it");
  const int64_t features = s.features, rows = s.table_size;
  const bool vector = vector_loops(form, features);
  with_features(features, [&](auto f) {
    constexpr int F = decltype(f)::value;
    at::parallel_for(0, s.levels, 1, [&](int64_t lo, int64_t hi) {
      for (int64_t l = lo; l < hi; ++l) {
        float* level_rows = grad_table + l * rows * features;
#ifdef ABLENERF_HAVE_AVX2_FORM
        if (vector) {
          const int level = static_cast<int>(l);
          if (l == lo) hash_grid_avx512::warm_level(grad_table, s, level, n);
          const auto next = l + 1 < hi ? hash_grid_avx512::next_level_stream(grad_table, s, level, n)
                                       : hash_grid_avx512::LevelStream();
          hash_grid_avx512::scatter_level(positions, n, grad_out, s, level, next, scales, level_rows);
          continue;
        }
#endif
        backward_level<F>(positions, n, grad_out, s, static_cast<int>(l), features, scales, level_rows);
      }
    });
  });
}

void hash_grid_forward_cpu(const float* positions, int64_t n, const float* table, const HashGridShape& s,
                           const float* scales, float* out) {
  hash_grid_forward_cpu_in(cpu_best_vector_form(), positions, n, table, s, scales, out);
}

void hash_grid_backward_cpu(const float* positions, int64_t n, const float* grad_out, const HashGridShape& s,
                            const float* scales, float* grad_table) {
  hash_grid_backward_cpu_in(cpu_best_vector_form(), positions, n, grad_out, s, scales, grad_table);
}

void hash_grid_backward_positions_cpu(const float* positions, int64_t n, const float* grad_out, const float* table,
                                      const HashGridShape& s, const float* scales, float* grad_positions) {
  const int64_t levels = s.levels, features = s.features, rows = s.table_size;
  at::parallel_for(0, n, kPointsPerTask, [&](int64_t lo, int64_t hi) {
    for (int64_t i = lo; i < hi; ++i) {
      float acc[3] = {0.f, 0.f, 0.f};
      for (int l = 0; l < levels; ++l) {
        const float* g = grad_out + (i * levels + l) * features;
        const float scale = scales != nullptr ? scales[i * levels + l] : 1.f;
        const float* level_rows = table + l * rows * features;
        hash_grid_corners_with_gradient(s, l, positions + 3 * i, [&](uint32_t row, float, const float* dw) {
          const float* r = level_rows + int64_t{row} * features;
          float dot = 0.f;
          for (int64_t f = 0; f < features; ++f) dot += g[f] * scale * r[f];
          for (int d = 0; d < 3; ++d) acc[d] += dot * dw[d];
        });
      }
      for (int d = 0; d < 3; ++d) grad_positions[3 * i + d] = acc[d];
    }
  });
}

}  // namespace ablenerf
