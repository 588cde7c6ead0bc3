#include "kernels/bf16_gemm.h"

#include <c10/util/Exception.h>

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <new>

#include "kernels/cpu_features.h"

#ifdef ABLENERF_HAVE_AVX2_FORM
#include <cpuid.h>
#include <immintrin.h>
#include <sys/syscall.h>
#include <unistd.h>
#if defined(__GNUC__) && !defined(__clang__) && __GNUC__ < 13
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#define ABLENERF_TARGET_AMX __attribute__((target("avx512f,avx512vl,avx512bw,avx512bf16,amx-tile,amx-bf16")))
#endif

namespace ablenerf {

namespace {

int64_t round_up(int64_t x, int64_t to) { return (x + to - 1) / to * to; }

#ifdef ABLENERF_HAVE_AVX2_FORM
bool cpuid_bit(unsigned leaf, unsigned sub, int reg, int bit) {
  unsigned r[4] = {0, 0, 0, 0};
  if (__get_cpuid_count(leaf, sub, &r[0], &r[1], &r[2], &r[3]) == 0) return false;
  return ((r[reg] >> bit) & 1u) != 0;
}

bool has_avx512_bf16() {
  // CPUID.(EAX=7, ECX=1):EAX bit 5; with AVX-512 F/VL (whose register state the OS saves) and BW.
  static const bool yes = cpu_has_avx512() && __builtin_cpu_supports("avx512bw") && cpuid_bit(7, 1, 0, 5);
  return yes;
}

bool has_amx() {
  // CPUID.(EAX=7, ECX=0):EDX bits 22 (AMX-BF16) and 24 (AMX-TILE); then Linux must grant the
  // process the tiles' register state (arch_prctl ARCH_REQ_XCOMP_PERM for XTILEDATA, Linux 5.16+).
  static const bool yes = [] {
    if (!has_avx512_bf16() || !cpuid_bit(7, 0, 3, 22) || !cpuid_bit(7, 0, 3, 24)) return false;
    constexpr long kArchReqXcompPerm = 0x1023, kXfeatureXtiledata = 18;
    return syscall(SYS_arch_prctl, kArchReqXcompPerm, kXfeatureXtiledata) == 0;
  }();
  return yes;
}
#else
bool has_amx() { return false; }
#endif

// ---- Reference form: the rounded operands in plain loops, sums in increasing p.

float bits_value(uint16_t h) {
  const uint32_t u = uint32_t{h} << 16;
  float x;
  std::memcpy(&x, &u, sizeof(x));
  return x;
}

// C = bf16(op(A)) B with op(A)(i, p) = a[i * si + p * sp]: A (si = lda, sp = 1) or A^T (si = 1,
// sp = lda).
void gemm_reference(int64_t m, const float* a, int64_t si, int64_t sp, const Bf16Operand& b, float* c, int64_t ldc) {
  const int64_t k = b.k(), n = b.n(), np = b.n_padded();
  const uint16_t* d = b.data();
  std::vector<float> row(static_cast<size_t>(k));
  for (int64_t i = 0; i < m; ++i) {
    for (int64_t p = 0; p < k; ++p) row[p] = bf16_round(a[i * si + p * sp]);
    for (int64_t j = 0; j < n; ++j) {
      float s = 0.f;
      for (int64_t p = 0; p < k; ++p) s += row[p] * bits_value(d[((p / 2) * np + j) * 2 + p % 2]);
      c[i * ldc + j] = s;
    }
  }
}

#ifdef ABLENERF_HAVE_AVX2_FORM
// The first `left` of 16 lanes (none when left <= 0, all when left >= 16).
ABLENERF_TARGET_AMX ABLENERF_ALWAYS_INLINE __mmask16 lanes_mask(int64_t left) {
  return left >= 16 ? __mmask16(0xffff) : left <= 0 ? __mmask16(0) : __mmask16((1u << left) - 1);
}

// Row i of A (k floats) as bfloat16 into `out` (kp values, zeros after k), 32 at a time.
ABLENERF_TARGET_AMX ABLENERF_ALWAYS_INLINE void convert_row(const float* a, int64_t k, int64_t kp, uint16_t* out) {
  for (int64_t p = 0; p < kp; p += 32) {
    const int64_t left = k - p;
    const __mmask16 lo = lanes_mask(left), hi = lanes_mask(left - 16);
    const __m512 x0 = _mm512_maskz_loadu_ps(lo, a + p), x1 = _mm512_maskz_loadu_ps(hi, a + p + 16);
    _mm512_store_si512(out + p, reinterpret_cast<__m512i>(_mm512_cvtne2ps_pbh(x1, x0)));
  }
}

// ---- Amx form: 32 rows of A converted at a time, 32 x 32 blocks of C in four tiles (tmm0-3), A in
// tmm4-5 and B in tmm6-7, 32 values of k per step.
struct alignas(64) TileConfig {
  uint8_t palette = 1;
  uint8_t start_row = 0;
  uint8_t reserved[14] = {};
  uint16_t colsb[16] = {};
  uint8_t rows[16] = {};
};

// Tiles 0-3 hold a 32 x 32 block of C, 4-5 two 16-row halves of A, 6-7 two 16-column halves of B;
// every tile 16 rows of 64 bytes.
ABLENERF_TARGET_AMX void configure_tiles() {
  TileConfig cfg;
  for (int t = 0; t < 8; ++t) {
    cfg.rows[t] = 16;
    cfg.colsb[t] = 64;
  }
  _tile_loadconfig(&cfg);
}

// C rows [0, rows) = arows (32 rows of kp bfloat16, rows past `rows` zero) times B, 32 x 32 blocks
// at a time over the whole reduction. Full blocks go straight into C; a block of fewer rows or
// columns through `cblock` (32 x np floats).
ABLENERF_TARGET_AMX void amx_rows(const uint16_t* arows, int64_t kp, const Bf16Operand& b, int64_t rows, float* c,
                                  int64_t ldc, float* cblock) {
  const int64_t n = b.n(), np = b.n_padded();
  const uint16_t* bd = b.data();
  const int64_t a_stride = kp * 2, b_stride = np * 4;
  const bool direct = rows == 32 && n == np;
  float* out = direct ? c : cblock;
  const int64_t ldo = direct ? ldc : np;
  for (int64_t j0 = 0; j0 < np; j0 += 32) {
    const bool two = j0 + 32 <= np;
    _tile_zero(0);
    _tile_zero(2);
    if (two) {
      _tile_zero(1);
      _tile_zero(3);
    }
    for (int64_t kk = 0; kk < kp; kk += 32) {
      _tile_loadd(4, arows + kk, a_stride);
      _tile_loadd(5, arows + 16 * kp + kk, a_stride);
      const uint16_t* bk = bd + ((kk / 2) * np + j0) * 2;
      _tile_loadd(6, bk, b_stride);
      _tile_dpbf16ps(0, 4, 6);
      _tile_dpbf16ps(2, 5, 6);
      if (two) {
        _tile_loadd(7, bk + 32, b_stride);
        _tile_dpbf16ps(1, 4, 7);
        _tile_dpbf16ps(3, 5, 7);
      }
    }
    _tile_stored(0, out + j0, ldo * 4);
    _tile_stored(2, out + 16 * ldo + j0, ldo * 4);
    if (two) {
      _tile_stored(1, out + j0 + 16, ldo * 4);
      _tile_stored(3, out + 16 * ldo + j0 + 16, ldo * 4);
    }
  }
  if (!direct)
    for (int64_t r = 0; r < rows; ++r)
      std::memcpy(c + r * ldc, cblock + r * np, static_cast<size_t>(n) * sizeof(float));
}

// The two thread-local buffers a product's blocks of 32 rows go through: A's rows in bfloat16
// (32 x kp) and a block of C (32 x np).
struct AmxScratch {
  uint16_t* arows;
  float* cblock;
};
AmxScratch amx_scratch(int64_t kp, int64_t np) {
  thread_local AlignedBuffer<uint16_t> a_buffer;
  thread_local AlignedFloats c_buffer;
  a_buffer.resize(static_cast<size_t>(32 * kp));
  c_buffer.resize(static_cast<size_t>(32 * np));
  return {a_buffer.data(), c_buffer.data()};
}

// Two rows' 16 bfloat16 values each, as VCVTNE2PS2BF16 leaves them (row 0 in the low half, row 1
// in the high), interleaved into 16 pairs (row 0's value, row 1's value): the tiles' pair layout.
ABLENERF_TARGET_AMX ABLENERF_ALWAYS_INLINE __m512i interleave_pairs(__m512bh rows) {
  alignas(64) static const int16_t order[32] = {0, 16, 1, 17, 2,  18, 3,  19, 4,  20, 5,  21, 6,  22, 7,  23,
                                                8, 24, 9, 25, 10, 26, 11, 27, 12, 28, 13, 29, 14, 30, 15, 31};
  return _mm512_permutexvar_epi16(_mm512_load_si512(order), reinterpret_cast<__m512i>(rows));
}

ABLENERF_TARGET_AMX void gemm_amx(int64_t m, const float* a, int64_t lda, const Bf16Operand& b, float* c, int64_t ldc) {
  const int64_t k = b.k(), kp = b.k_padded();
  configure_tiles();
  const AmxScratch scratch = amx_scratch(kp, b.n_padded());
  uint16_t* arows = scratch.arows;
  float* cblock = scratch.cblock;
  for (int64_t i0 = 0; i0 < m; i0 += 32) {
    const int64_t rows = std::min<int64_t>(32, m - i0);
    for (int64_t r = 0; r < rows; ++r) convert_row(a + (i0 + r) * lda, k, kp, arows + r * kp);
    if (rows < 32) std::memset(arows + rows * kp, 0, static_cast<size_t>((32 - rows) * kp) * sizeof(uint16_t));
    amx_rows(arows, kp, b, rows, c + i0 * ldc, ldc, cblock);
  }
  _tile_release();
}

// 16 vectors of 16 32-bit values transposed in registers: r[i] lane j <- r[j] lane i.
ABLENERF_TARGET_AMX ABLENERF_ALWAYS_INLINE void transpose16(__m512i r[16]) {
  __m512i t[16];
  for (int i = 0; i < 8; ++i) {
    t[2 * i] = _mm512_unpacklo_epi32(r[2 * i], r[2 * i + 1]);
    t[2 * i + 1] = _mm512_unpackhi_epi32(r[2 * i], r[2 * i + 1]);
  }
  // r[4i + j], 128-bit lane k: rows 4i..4i+3 of column 4k + j.
  for (int i = 0; i < 4; ++i) {
    r[4 * i] = _mm512_unpacklo_epi64(t[4 * i], t[4 * i + 2]);
    r[4 * i + 1] = _mm512_unpackhi_epi64(t[4 * i], t[4 * i + 2]);
    r[4 * i + 2] = _mm512_unpacklo_epi64(t[4 * i + 1], t[4 * i + 3]);
    r[4 * i + 3] = _mm512_unpackhi_epi64(t[4 * i + 1], t[4 * i + 3]);
  }
  for (int j = 0; j < 4; ++j) {
    const __m512i s0 = _mm512_shuffle_i32x4(r[j], r[4 + j], 0x88), s1 = _mm512_shuffle_i32x4(r[j], r[4 + j], 0xdd);
    const __m512i s2 = _mm512_shuffle_i32x4(r[8 + j], r[12 + j], 0x88),
                  s3 = _mm512_shuffle_i32x4(r[8 + j], r[12 + j], 0xdd);
    t[j] = _mm512_shuffle_i32x4(s0, s2, 0x88);       // column j
    t[8 + j] = _mm512_shuffle_i32x4(s0, s2, 0xdd);   // column 8 + j
    t[4 + j] = _mm512_shuffle_i32x4(s1, s3, 0x88);   // column 4 + j
    t[12 + j] = _mm512_shuffle_i32x4(s1, s3, 0xdd);  // column 12 + j
  }
  for (int i = 0; i < 16; ++i) r[i] = t[i];
}

// C (m x n) = bf16(A)^T B for A (k x m): 32 columns of A at a time made 32 rows of bfloat16 (pairs
// of A's rows converted and interleaved, as B's packing, then 16 x 16 blocks of those pairs
// transposed in registers).
ABLENERF_TARGET_AMX void gemm_amx_at(int64_t m, const float* a, int64_t lda, const Bf16Operand& b, float* c,
                                     int64_t ldc) {
  const int64_t k = b.k(), kp = b.k_padded();
  configure_tiles();
  const AmxScratch scratch = amx_scratch(kp, b.n_padded());
  uint16_t* arows = scratch.arows;
  float* cblock = scratch.cblock;
  for (int64_t i0 = 0; i0 < m; i0 += 32) {
    const int64_t rows = std::min<int64_t>(32, m - i0);
    for (int64_t h = 0; h < 32; h += 16) {
      const __mmask16 cols = lanes_mask(rows - h);
      for (int64_t p0 = 0; p0 < kp; p0 += 32) {
        __m512i u[16];
        for (int q = 0; q < 16; ++q) {
          const int64_t p = p0 + 2 * q;
          const __m512 x0 = p < k ? _mm512_maskz_loadu_ps(cols, a + p * lda + i0 + h) : _mm512_setzero_ps();
          const __m512 x1 = p + 1 < k ? _mm512_maskz_loadu_ps(cols, a + (p + 1) * lda + i0 + h) : _mm512_setzero_ps();
          u[q] = interleave_pairs(_mm512_cvtne2ps_pbh(x1, x0));
        }
        transpose16(u);
        for (int r = 0; r < 16; ++r) _mm512_store_si512(arows + (h + r) * kp + p0, u[r]);
      }
    }
    amx_rows(arows, kp, b, rows, c + i0 * ldc, ldc, cblock);
  }
  _tile_release();
}

// Bf16Operand::pack for B with contiguous rows (col_stride 1: each pair of rows converted 16
// columns at a time, VCVTNE2PS2BF16, and interleaved, VPERMW) or contiguous columns (row_stride 1,
// B = W^T: each row of W converted 32 values at a time, its 16 pairs scattered np apart).
ABLENERF_TARGET_AMX void pack_vectors(const float* b, int64_t k, int64_t n, int64_t row_stride, int64_t col_stride,
                                      int64_t np, uint16_t* d) {
  if (col_stride == 1) {
    for (int64_t p = 0; p < k; p += 2) {
      const float* r0 = b + p * row_stride;
      const float* r1 = p + 1 < k ? r0 + row_stride : nullptr;
      for (int64_t j0 = 0; j0 < n; j0 += 16) {
        const __mmask16 m = lanes_mask(n - j0);
        const __m512 x0 = _mm512_maskz_loadu_ps(m, r0 + j0);
        const __m512 x1 = r1 != nullptr ? _mm512_maskz_loadu_ps(m, r1 + j0) : _mm512_setzero_ps();
        _mm512_store_si512(d + ((p / 2) * np + j0) * 2, interleave_pairs(_mm512_cvtne2ps_pbh(x1, x0)));
      }
    }
    return;
  }
  const __m512i lanes = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  auto* d32 = reinterpret_cast<int32_t*>(d);
  for (int64_t j = 0; j < n; ++j) {
    const float* w = b + j * col_stride;
    for (int64_t p0 = 0; p0 < k; p0 += 32) {
      const __m512 x0 = _mm512_maskz_loadu_ps(lanes_mask(k - p0), w + p0);
      const __m512 x1 = _mm512_maskz_loadu_ps(lanes_mask(k - p0 - 16), w + p0 + 16);
      const __m512i pairs = reinterpret_cast<__m512i>(_mm512_cvtne2ps_pbh(x1, x0));
      // Pair q = p0 / 2 + lane goes to d32[q * np + j]; pairs past k are zeros already.
      const __m512i at =
          _mm512_add_epi32(_mm512_mullo_epi32(_mm512_add_epi32(lanes, _mm512_set1_epi32(static_cast<int>(p0 / 2))),
                                              _mm512_set1_epi32(static_cast<int>(np))),
                           _mm512_set1_epi32(static_cast<int>(j)));
      _mm512_mask_i32scatter_epi32(d32, lanes_mask((k - p0 + 1) / 2), at, pairs, 4);
    }
  }
}
#endif

}  // namespace

bool bf16_gemm_form_available(Bf16GemmForm form) {
  switch (form) {
    case Bf16GemmForm::Amx: return has_amx();
    case Bf16GemmForm::Reference: return true;
  }
  return false;
}

Bf16GemmForm bf16_gemm_best_form() {
  static const Bf16GemmForm best = has_amx() ? Bf16GemmForm::Amx : Bf16GemmForm::Reference;
  return best;
}

bool cpu_has_bf16_products() { return bf16_gemm_best_form() != Bf16GemmForm::Reference; }

const char* bf16_gemm_form_name(Bf16GemmForm form) {
  switch (form) {
    case Bf16GemmForm::Amx: return "amx";
    case Bf16GemmForm::Reference: return "reference";
  }
  return "?";
}

uint16_t bf16_bits(float x) {
  uint32_t u;
  std::memcpy(&u, &x, sizeof(u));
  if ((u & 0x7f800000u) == 0) return static_cast<uint16_t>((u & 0x80000000u) >> 16);     // zero, subnormal
  if ((u & 0x7fffffffu) > 0x7f800000u) return static_cast<uint16_t>((u >> 16) | 0x40u);  // NaN, quiet
  u += 0x7fffu + ((u >> 16) & 1u);
  return static_cast<uint16_t>(u >> 16);
}

float bf16_round(float x) { return bits_value(bf16_bits(x)); }

void Bf16Operand::pack(const float* b, int64_t k, int64_t n, int64_t row_stride, int64_t col_stride,
                       Bf16GemmForm form) {
  TORCH_CHECK(k > 0 && n > 0, "bf16_gemm: B must have k >= 1 rows and n >= 1 columns, got ", k, " x ", n);
  k_ = k;
  n_ = n;
  k_padded_ = round_up(k, 32);
  n_padded_ = round_up(n, 16);
  const size_t count = static_cast<size_t>(k_padded_ * n_padded_);
  data_.resize(count);
  uint16_t* d = data_.data();
  std::memset(d, 0, count * sizeof(uint16_t));
#ifdef ABLENERF_HAVE_AVX2_FORM
  if (form == Bf16GemmForm::Amx && (col_stride == 1 || row_stride == 1)) {
    TORCH_CHECK(has_amx(), "bf16_gemm: form amx does not run on this CPU");
    pack_vectors(b, k, n, row_stride, col_stride, n_padded_, d);
    return;
  }
#endif
  for (int64_t p = 0; p < k; ++p)
    for (int64_t j = 0; j < n; ++j)
      d[((p / 2) * n_padded_ + j) * 2 + p % 2] = bf16_bits(b[p * row_stride + j * col_stride]);
}

namespace {
void check_product(const char* op, Bf16GemmForm form, int64_t m, int64_t lda, int64_t a_min, const Bf16Operand& b,
                   int64_t ldc) {
  TORCH_CHECK(bf16_gemm_form_available(form), op, ": form ", bf16_gemm_form_name(form), " does not run on this CPU");
  TORCH_CHECK(b.data() != nullptr, op, ": B is not packed");
  TORCH_CHECK(m >= 0, op, ": m must be >= 0, got ", m);
  TORCH_CHECK(lda >= a_min, op, ": lda must be >= ", a_min, ", got ", lda);
  TORCH_CHECK(ldc >= b.n(), op, ": ldc must be >= n (", b.n(), "), got ", ldc);
}
}  // namespace

void bf16_gemm_in(Bf16GemmForm form, int64_t m, const float* a, int64_t lda, const Bf16Operand& b, float* c,
                  int64_t ldc) {
  check_product("bf16_gemm", form, m, lda, b.k(), b, ldc);
  if (m == 0) return;
#ifdef ABLENERF_HAVE_AVX2_FORM
  if (form == Bf16GemmForm::Amx) return gemm_amx(m, a, lda, b, c, ldc);
#endif
  gemm_reference(m, a, lda, 1, b, c, ldc);
}

void bf16_gemm(int64_t m, const float* a, int64_t lda, const Bf16Operand& b, float* c, int64_t ldc) {
  bf16_gemm_in(bf16_gemm_best_form(), m, a, lda, b, c, ldc);
}

void bf16_gemm_at_in(Bf16GemmForm form, int64_t m, const float* a, int64_t lda, const Bf16Operand& b, float* c,
                     int64_t ldc) {
  check_product("bf16_gemm_at", form, m, lda, m, b, ldc);
  if (m == 0) return;
#ifdef ABLENERF_HAVE_AVX2_FORM
  if (form == Bf16GemmForm::Amx) return gemm_amx_at(m, a, lda, b, c, ldc);
#endif
  gemm_reference(m, a, 1, lda, b, c, ldc);
}

void bf16_gemm_at(int64_t m, const float* a, int64_t lda, const Bf16Operand& b, float* c, int64_t ldc) {
  bf16_gemm_at_in(bf16_gemm_best_form(), m, a, lda, b, c, ldc);
}

}  // namespace ablenerf
