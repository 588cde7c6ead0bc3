// Fused self-attention over the tokens of one ray (forward and backward), read straight from the
// packed projection. One thread block per (ray, head): the head's Q, K and V (at most 128 x 64)
// sit in shared memory, the scores and the softmax never leave the chip, and the ray mask skips
// the blocked half of every product. See ray_attention_launch.h for the layouts.
//
// Two implementations, one per input type:
//  * fp32: CUDA cores, every thread computing 4 x 4 blocks of each product from shared memory;
//  * bf16: tensor cores (WMMA 16 x 16 x 16, bf16 -> fp32) on tiles padded to 16 rows. Forward:
//    one warp per 16-row strip of the scores, so that the softmax needs no block-wide barrier.
//    Backward: one warp per 16-key strip recomputes P and dS tile by tile from the saved
//    log-sum-exp and accumulates dK and dV in registers, keeping only dS in shared memory (104 KB
//    at L = 97: two blocks per SM); then one warp per 16-row strip forms dQ from dS.
// Loads are cp.async copies, all of a block's in flight together (one at a time per thread made
// the kernels wait on memory latency).
#include <cuda_bf16.h>
#include <math_constants.h>
#include <mma.h>

#include "kernels/cuda_common.cuh"
#include "kernels/ray_attention_launch.h"

namespace ablenerf::kernels {

namespace {

constexpr int kDh = kRayAttentionHeadDim;
constexpr unsigned kFullMask = 0xffffffffu;

// The last column row i may attend to.
__device__ __forceinline__ int last_column(int i, int tokens, bool masked) { return masked && i > 0 ? i : tokens - 1; }

using cuda_detail::warp_max;
using cuda_detail::warp_sum;

// Asynchronous copy of N (4 or 16) bytes from global to shared memory (cp.async, sm_80+), or of N
// zero bytes when !valid (src is then not read, but must still be a mapped address). Every thread
// issues all of its copies before waiting, so that the block's loads are in flight together.
template <int N>
__device__ __forceinline__ void copy_async(void* dst, const void* src, bool valid) {
  static_assert(N == 4 || N == 16, "cp.async copies 4 or 16 bytes here");
  const unsigned d = static_cast<unsigned>(__cvta_generic_to_shared(dst));
  if constexpr (N == 16) {
    asm volatile("cp.async.cg.shared.global [%0], [%1], 16, %2;\n" ::"r"(d), "l"(src), "r"(valid ? 16 : 0) : "memory");
  } else {
    asm volatile("cp.async.ca.shared.global [%0], [%1], 4, %2;\n" ::"r"(d), "l"(src), "r"(valid ? 4 : 0) : "memory");
  }
}

// Waits for this thread's copies; a barrier must follow before other threads read them.
__device__ __forceinline__ void copy_async_wait() { asm volatile("cp.async.wait_all;\n" ::: "memory"); }

// =============================================================================================
// fp32 on CUDA cores.
// =============================================================================================

constexpr int kFp32Threads = 512;
constexpr int kHeadStride = kDh + 1;  // odd row stride of the (rows x 64) operands: fewer bank conflicts

// Rows multiple of 4 (the products' block size).
__host__ __device__ inline int fp32_padded(int tokens) { return (tokens + 3) / 4 * 4; }

// Shared memory of the forward: Q, K, V (padded x kHeadStride) and the scores (padded x (padded+1)).
inline size_t fp32_forward_smem(int tokens) {
  const size_t p = fp32_padded(tokens);
  return (3 * p * kHeadStride + p * (p + 1)) * sizeof(float);
}

// Floats of the backward's square buffer: P, then dS; O before both (for D).
__host__ __device__ inline int fp32_square(int padded) {
  return padded * (padded + 1) > padded * kHeadStride ? padded * (padded + 1) : padded * kHeadStride;
}

// Of the backward: Q, K, V, dO, the square buffer, and two per-row vectors.
inline size_t fp32_backward_smem(int tokens) {
  const size_t p = fp32_padded(tokens);
  return (4 * p * kHeadStride + fp32_square(int(p)) + 2 * p) * sizeof(float);
}

// The summation range of one 4 x 4 block of a product: k in [begin, end), plus k = 0 when
// with_first is set and begin > 0 (row 0 of the mask sees every column).
struct KRange {
  int begin, end;
  bool with_first;
};

// C (m x n) = sum_k A(i, k) B(k, j), every thread taking 4 x 4 blocks in turn. m and n are
// multiples of 4; a(i, k) and b(k, j) read the operands (any layout), range(i0, j0) gives the k
// range of the block at (i0, j0), store(i0, j0, acc) receives the block (also an empty one).
template <class A, class B, class Range, class Store>
__device__ __forceinline__ void block_product(int m, int n, const A& a, const B& b, const Range& range,
                                              const Store& store) {
  const int col_blocks = n / 4, blocks = (m / 4) * col_blocks;
  for (int t = threadIdx.x; t < blocks; t += blockDim.x) {
    const int i0 = (t / col_blocks) * 4, j0 = (t % col_blocks) * 4;
    const KRange kr = range(i0, j0);
    float acc[4][4] = {};
    const auto step = [&](int k) {
      float av[4], bv[4];
#pragma unroll
      for (int r = 0; r < 4; ++r) av[r] = a(i0 + r, k);
#pragma unroll
      for (int c = 0; c < 4; ++c) bv[c] = b(k, j0 + c);
#pragma unroll
      for (int r = 0; r < 4; ++r)
#pragma unroll
        for (int c = 0; c < 4; ++c) acc[r][c] = fmaf(av[r], bv[c], acc[r][c]);
    };
    if (kr.with_first && kr.begin > 0) step(0);
    for (int k = kr.begin; k < kr.end; ++k) step(k);
    store(i0, j0, acc);
  }
}

// Starts copying rows [0, padded) of a head's (tokens x 64) matrix, rows `row_stride` apart, into
// dst (kHeadStride apart); rows >= tokens become zero.
__device__ void load_head_fp32(const float* __restrict__ src, int64_t row_stride, int tokens, int padded,
                               float* __restrict__ dst) {
  for (int e = threadIdx.x; e < padded * kDh; e += blockDim.x) {
    const int i = e / kDh, d = e % kDh;
    copy_async<4>(dst + i * kHeadStride + d, i < tokens ? src + i * row_stride + d : src, i < tokens);
  }
}

// The k range of a scores block (rows i0.., columns j0..): empty when the mask blocks all of it.
__device__ __forceinline__ KRange score_range(int i0, int j0, bool masked) {
  return KRange{0, masked && i0 > 0 && j0 > i0 + 3 ? 0 : kDh, false};
}

// Range over columns (keys) for the rows i0..i0+3 of a (rows x keys) x (keys x 64) product.
__device__ __forceinline__ KRange key_range(int i0, int tokens, bool masked) {
  return KRange{0, masked && i0 > 0 ? min(i0 + 4, tokens) : tokens, false};
}

// Range over rows (queries) that see the columns j0..j0+3: row 0 and rows >= j0 when masked.
__device__ __forceinline__ KRange query_range(int j0, int tokens, bool masked) {
  return masked ? KRange{j0, tokens, true} : KRange{0, tokens, false};
}

__global__ void __launch_bounds__(kFp32Threads)
    forward_fp32(const float* __restrict__ qkv, float* __restrict__ out, float* __restrict__ lse,
                 float* __restrict__ row0, int tokens, int heads, bool masked, float scale) {
  const int64_t item = blockIdx.x;  // ray * heads + head
  const int64_t ray = item / heads;
  const int head = int(item % heads);
  const int width = heads * kDh;
  const int64_t stride = 3 * int64_t(width);
  const int padded = fp32_padded(tokens), ls = padded + 1;
  const float* src = qkv + ray * tokens * stride + head * kDh;

  extern __shared__ float smem[];
  float* q = smem;
  float* k = q + padded * kHeadStride;
  float* v = k + padded * kHeadStride;
  float* s = v + padded * kHeadStride;
  load_head_fp32(src, stride, tokens, padded, q);
  load_head_fp32(src + width, stride, tokens, padded, k);
  load_head_fp32(src + 2 * width, stride, tokens, padded, v);
  copy_async_wait();
  __syncthreads();

  block_product(
      padded, padded, [&](int i, int c) { return q[i * kHeadStride + c]; },
      [&](int c, int j) { return k[j * kHeadStride + c]; }, [&](int i0, int j0) { return score_range(i0, j0, masked); },
      [&](int i0, int j0, const float(&acc)[4][4]) {
#pragma unroll
        for (int r = 0; r < 4; ++r)
#pragma unroll
          for (int c = 0; c < 4; ++c) s[(i0 + r) * ls + j0 + c] = acc[r][c] * scale;
      });
  __syncthreads();

  // Softmax, one warp per row; blocked and padded columns become 0.
  const int warp = threadIdx.x / 32, lane = threadIdx.x % 32, warps = blockDim.x / 32;
  for (int i = warp; i < padded; i += warps) {
    float* row = s + i * ls;
    if (i >= tokens) {
      for (int j = lane; j < padded; j += 32) row[j] = 0.f;
      continue;
    }
    const int last = last_column(i, tokens, masked);
    float m = -CUDART_INF_F;
    for (int j = lane; j <= last; j += 32) m = fmaxf(m, row[j]);
    m = warp_max(m);
    float sum = 0.f;
    for (int j = lane; j <= last; j += 32) {
      const float e = expf(row[j] - m);
      row[j] = e;
      sum += e;
    }
    sum = warp_sum(sum);
    const float inv = 1.f / sum;
    for (int j = lane; j < padded; j += 32) row[j] = j <= last ? row[j] * inv : 0.f;
    if (lane == 0) lse[item * tokens + i] = m + logf(sum);
    if (i == 0)
      for (int j = lane; j < tokens; j += 32) row0[item * tokens + j] = row[j];
  }
  __syncthreads();

  float* o = out + ray * tokens * width + head * kDh;
  block_product(
      padded, kDh, [&](int i, int c) { return s[i * ls + c]; }, [&](int c, int d) { return v[c * kHeadStride + d]; },
      [&](int i0, int) { return key_range(i0, tokens, masked); },
      [&](int i0, int d0, const float(&acc)[4][4]) {
#pragma unroll
        for (int r = 0; r < 4; ++r) {
          if (i0 + r >= tokens) break;
#pragma unroll
          for (int c = 0; c < 4; ++c) o[(i0 + r) * width + d0 + c] = acc[r][c];
        }
      });
}

__global__ void __launch_bounds__(kFp32Threads)
    backward_fp32(const float* __restrict__ qkv, const float* __restrict__ out, const float* __restrict__ grad_out,
                  const float* __restrict__ lse, float* __restrict__ grad_qkv, int tokens, int heads, bool masked,
                  float scale) {
  const int64_t item = blockIdx.x;
  const int64_t ray = item / heads;
  const int head = int(item % heads);
  const int width = heads * kDh;
  const int64_t stride = 3 * int64_t(width);
  const int padded = fp32_padded(tokens), ls = padded + 1;
  const float* src = qkv + ray * tokens * stride + head * kDh;
  const int64_t head_offset = ray * tokens * width + head * kDh;  // into out / grad_out

  extern __shared__ float smem[];
  float* q = smem;
  float* k = q + padded * kHeadStride;
  float* v = k + padded * kHeadStride;
  float* g = v + padded * kHeadStride;    // dO
  float* p = g + padded * kHeadStride;    // O (kHeadStride apart), then P, then dS in place
  float* dvec = p + fp32_square(padded);  // D_i = dO_i . O_i
  float* lrow = dvec + padded;            // the forward's log-sum-exp
  load_head_fp32(src, stride, tokens, padded, q);
  load_head_fp32(src + width, stride, tokens, padded, k);
  load_head_fp32(src + 2 * width, stride, tokens, padded, v);
  load_head_fp32(grad_out + head_offset, width, tokens, padded, g);
  load_head_fp32(out + head_offset, width, tokens, padded, p);
  for (int i = threadIdx.x; i < padded; i += blockDim.x) lrow[i] = i < tokens ? lse[item * tokens + i] : 0.f;
  copy_async_wait();
  __syncthreads();
  const int warp = threadIdx.x / 32, lane = threadIdx.x % 32, warps = blockDim.x / 32;
  for (int i = warp; i < padded; i += warps) {
    float d = 0.f;
    for (int c = lane; c < kDh; c += 32) d += p[i * kHeadStride + c] * g[i * kHeadStride + c];
    d = warp_sum(d);
    if (lane == 0) dvec[i] = d;
  }
  __syncthreads();

  // P recomputed from the scores and the saved log-sum-exp; 0 where blocked or padded.
  block_product(
      padded, padded, [&](int i, int c) { return q[i * kHeadStride + c]; },
      [&](int c, int j) { return k[j * kHeadStride + c]; }, [&](int i0, int j0) { return score_range(i0, j0, masked); },
      [&](int i0, int j0, const float(&acc)[4][4]) {
#pragma unroll
        for (int r = 0; r < 4; ++r) {
          const int i = i0 + r;
          const int last = i < tokens ? last_column(i, tokens, masked) : -1;
#pragma unroll
          for (int c = 0; c < 4; ++c) p[i * ls + j0 + c] = j0 + c <= last ? expf(acc[r][c] * scale - lrow[i]) : 0.f;
        }
      });
  __syncthreads();

  float* gq = grad_qkv + ray * tokens * stride + head * kDh;
  float* gk = gq + width;
  float* gv = gq + 2 * width;
  // dV = P^T dO.
  block_product(
      padded, kDh, [&](int j, int i) { return p[i * ls + j]; }, [&](int i, int d) { return g[i * kHeadStride + d]; },
      [&](int j0, int) { return query_range(j0, tokens, masked); },
      [&](int j0, int d0, const float(&acc)[4][4]) {
#pragma unroll
        for (int r = 0; r < 4; ++r) {
          if (j0 + r >= tokens) break;
#pragma unroll
          for (int c = 0; c < 4; ++c) gv[(j0 + r) * stride + d0 + c] = acc[r][c];
        }
      });
  __syncthreads();

  // dS = P * (dP - D) with dP = dO V^T, in place of P (each element read and written by one thread).
  block_product(
      padded, padded, [&](int i, int c) { return g[i * kHeadStride + c]; },
      [&](int c, int j) { return v[j * kHeadStride + c]; }, [&](int i0, int j0) { return score_range(i0, j0, masked); },
      [&](int i0, int j0, const float(&acc)[4][4]) {
#pragma unroll
        for (int r = 0; r < 4; ++r)
#pragma unroll
          for (int c = 0; c < 4; ++c) {
            float& x = p[(i0 + r) * ls + j0 + c];
            x = x * (acc[r][c] - dvec[i0 + r]);
          }
      });
  __syncthreads();

  // dQ = scale dS K;  dK = scale dS^T Q.
  block_product(
      padded, kDh, [&](int i, int j) { return p[i * ls + j]; }, [&](int j, int d) { return k[j * kHeadStride + d]; },
      [&](int i0, int) { return key_range(i0, tokens, masked); },
      [&](int i0, int d0, const float(&acc)[4][4]) {
#pragma unroll
        for (int r = 0; r < 4; ++r) {
          if (i0 + r >= tokens) break;
#pragma unroll
          for (int c = 0; c < 4; ++c) gq[(i0 + r) * stride + d0 + c] = acc[r][c] * scale;
        }
      });
  block_product(
      padded, kDh, [&](int j, int i) { return p[i * ls + j]; }, [&](int i, int d) { return q[i * kHeadStride + d]; },
      [&](int j0, int) { return query_range(j0, tokens, masked); },
      [&](int j0, int d0, const float(&acc)[4][4]) {
#pragma unroll
        for (int r = 0; r < 4; ++r) {
          if (j0 + r >= tokens) break;
#pragma unroll
          for (int c = 0; c < 4; ++c) gk[(j0 + r) * stride + d0 + c] = acc[r][c] * scale;
        }
      });
}

// =============================================================================================
// bf16 on tensor cores.
// =============================================================================================

namespace wmma = nvcuda::wmma;
using bf16 = __nv_bfloat16;
using FragA = wmma::fragment<wmma::matrix_a, 16, 16, 16, bf16, wmma::row_major>;
using FragAT = wmma::fragment<wmma::matrix_a, 16, 16, 16, bf16, wmma::col_major>;  // a transposed operand
using FragB = wmma::fragment<wmma::matrix_b, 16, 16, 16, bf16, wmma::row_major>;
using FragBT = wmma::fragment<wmma::matrix_b, 16, 16, 16, bf16, wmma::col_major>;
using FragC = wmma::fragment<wmma::accumulator, 16, 16, 16, float>;

constexpr int kHeadLd = kDh + 8;     // bf16 row stride of the (rows x 64) operands in shared memory
constexpr int kTileLd = 16 + 4;      // fp32 row stride of a warp's 16 x 16 tile
constexpr int kHalfTileLd = 16 + 8;  // bf16 row stride of a warp's 16 x 16 tile
constexpr int kMaxTcWarps = 8;
static_assert(kRayAttentionMaxTokens <= 16 * kMaxTcWarps, "one warp per 16-row strip");

// The geometry every bf16 kernel and its launch agree on. Row strides are multiples of 8 bf16 /
// 4 floats (WMMA's rule) and every region starts 32-byte aligned (WMMA's pointer rule).
struct TcGeometry {
  int tiles;   // 16-row tiles covering the tokens
  int padded;  // 16 * tiles
  int ldp;     // bf16 row stride of the backward's (padded x padded) dS
  int lds;     // fp32 row stride of a forward warp's 16-row strip (scores, then 16 x 64 results)
  int ldh;     // bf16 row stride of a forward warp's 16-row P (its strip of Q before that)
  int warps;   // warps per block, one 16-row (or 16-column) strip each
  __host__ __device__ explicit TcGeometry(int tokens)
      : tiles((tokens + 15) / 16),
        padded(16 * tiles),
        ldp(padded + 8),
        lds((padded > kDh ? padded : kDh) + 4),
        ldh((padded > kDh ? padded : kDh) + 8),
        warps(tiles) {}
  __host__ __device__ size_t head_bytes() const { return size_t(padded) * kHeadLd * sizeof(bf16); }
  // Forward: K, V, then per warp a 16-row fp32 strip and a 16-row bf16 strip.
  __host__ __device__ size_t strip_bytes() const {
    return size_t(16) * lds * sizeof(float) + size_t(16) * ldh * sizeof(bf16);
  }
  __host__ __device__ size_t forward_smem() const { return 2 * head_bytes() + warps * strip_bytes(); }
  // Backward: Q, K, V, dO, the square dS (holding O first, for D), D and the log-sum-exp, then
  // per warp an fp32 and a bf16 16 x 16 tile.
  __host__ __device__ size_t square_bytes() const {
    const size_t ds = size_t(padded) * ldp * sizeof(bf16);
    return ds > head_bytes() ? ds : head_bytes();
  }
  __host__ __device__ size_t tile_bytes() const {
    return 16 * kTileLd * sizeof(float) + 16 * kHalfTileLd * sizeof(bf16);
  }
  __host__ __device__ size_t backward_smem() const {
    return 4 * head_bytes() + square_bytes() + 2 * padded * sizeof(float) + warps * tile_bytes();
  }
};

// Starts copying rows [0, padded) of a head's (tokens x 64) bf16 matrix (rows row_stride apart;
// 16-byte aligned) into dst (kHeadLd apart), all threads of the block; rows >= tokens become zero.
__device__ __forceinline__ void load_head_bf16(const bf16* __restrict__ src, int64_t row_stride, int tokens, int padded,
                                               bf16* __restrict__ dst) {
  constexpr int kChunks = kDh / 8;  // 16-byte chunks per row
  for (int e = threadIdx.x; e < padded * kChunks; e += blockDim.x) {
    const int i = e / kChunks, c = (e % kChunks) * 8;
    copy_async<16>(dst + i * kHeadLd + c, i < tokens ? src + i * row_stride + c : src, i < tokens);
  }
}

// 16 x 8 bf16 values (8 fp32 per row at x, rows ld apart, times factor) into rows [row0, row0 + 16)
// of dst at column col (rows row_stride apart), skipping rows >= tokens: one 16-byte store per lane
// for a 16 x 16 tile (lanes 0..31 = row lane / 2, half lane % 2).
__device__ __forceinline__ void store_tile_bf16(const float* tile, int ld, float factor, bf16* __restrict__ dst,
                                                int64_t row_stride, int row0, int col, int tokens, int lane) {
  const int r = lane / 2, half = (lane % 2) * 8, i = row0 + r;
  if (i >= tokens) return;
  const float* x = tile + r * ld + half;
  union {
    uint4 u;
    __nv_bfloat162 h[4];
  } pack;
#pragma unroll
  for (int t = 0; t < 4; ++t) pack.h[t] = __floats2bfloat162_rn(x[2 * t] * factor, x[2 * t + 1] * factor);
  *reinterpret_cast<uint4*>(dst + i * row_stride + col + half) = pack.u;
}

// One warp per 16-row strip of queries: its scores against the visible key tiles, the softmax of
// its rows (two lanes per row), then its rows of O.
__global__ void __launch_bounds__(32 * kMaxTcWarps)
    forward_bf16(const bf16* __restrict__ qkv, bf16* __restrict__ out, float* __restrict__ lse,
                 float* __restrict__ row0, int tokens, int heads, bool masked, float scale) {
  const TcGeometry geo(tokens);
  const int64_t item = blockIdx.x;
  const int64_t ray = item / heads;
  const int head = int(item % heads);
  const int width = heads * kDh;
  const int64_t stride = 3 * int64_t(width);
  const bf16* src = qkv + ray * tokens * stride + head * kDh;

  extern __shared__ __align__(128) unsigned char smem_bytes[];
  bf16* ks = reinterpret_cast<bf16*>(smem_bytes);
  bf16* vs = ks + geo.padded * kHeadLd;
  const int warp = threadIdx.x / 32, lane = threadIdx.x % 32;
  float* strip = reinterpret_cast<float*>(smem_bytes + 2 * geo.head_bytes() + warp * geo.strip_bytes());
  bf16* half_strip = reinterpret_cast<bf16*>(strip + 16 * geo.lds);  // this strip's Q, then its P
  const int r0 = 16 * warp;
  load_head_bf16(src + width, stride, tokens, geo.padded, ks);
  load_head_bf16(src + 2 * width, stride, tokens, geo.padded, vs);
  for (int e = lane; e < 16 * (kDh / 8); e += 32) {  // this warp's rows of Q
    const int r = e / (kDh / 8), c = (e % (kDh / 8)) * 8, i = r0 + r;
    copy_async<16>(half_strip + r * kHeadLd + c, i < tokens ? src + i * stride + c : src, i < tokens);
  }
  copy_async_wait();
  __syncthreads();

  const int col_tiles = masked && warp > 0 ? warp + 1 : geo.tiles;  // tiles right of the diagonal are blocked
  const int cols = 16 * col_tiles;

  // Scores of the strip (unscaled).
  FragA qa[kDh / 16];
#pragma unroll
  for (int kk = 0; kk < kDh / 16; ++kk) wmma::load_matrix_sync(qa[kk], half_strip + 16 * kk, kHeadLd);
  for (int ct = 0; ct < col_tiles; ++ct) {
    FragC acc;
    wmma::fill_fragment(acc, 0.f);
#pragma unroll
    for (int kk = 0; kk < kDh / 16; ++kk) {
      FragBT kb;
      wmma::load_matrix_sync(kb, ks + 16 * ct * kHeadLd + 16 * kk, kHeadLd);
      wmma::mma_sync(acc, qa[kk], kb, acc);
    }
    wmma::store_matrix_sync(strip + 16 * ct, acc, geo.lds, wmma::mem_row_major);
  }
  __syncwarp();

  // Softmax in fp32, lanes 2r and 2r + 1 on row r (even and odd columns): exp values over the
  // scores, then P as bf16 into the half strip (zero on blocked and padded columns).
  {
    const int r = lane / 2, h = lane % 2, i = r0 + r;
    const int last = i < tokens ? last_column(i, tokens, masked) : -1;
    float* srow = strip + r * geo.lds;
    float m = -CUDART_INF_F;
    for (int j = h; j <= last; j += 2) m = fmaxf(m, srow[j]);
    m = fmaxf(m, __shfl_xor_sync(kFullMask, m, 1)) * scale;
    float sum = 0.f;
    for (int j = h; j <= last; j += 2) {
      const float e = expf(srow[j] * scale - m);
      srow[j] = e;
      sum += e;
    }
    sum += __shfl_xor_sync(kFullMask, sum, 1);
    const float inv = last >= 0 ? 1.f / sum : 0.f;
    bf16* prow = half_strip + r * geo.ldh;
    for (int j = h; j < cols; j += 2) {
      const float pv = j <= last ? srow[j] * inv : 0.f;
      prow[j] = __float2bfloat16_rn(pv);
      if (i == 0 && j < tokens) row0[item * tokens + j] = pv;
    }
    if (last >= 0 && h == 0) lse[item * tokens + i] = m + logf(sum);
  }
  __syncwarp();

  // O = P V over the visible key tiles.
  FragC acc[kDh / 16];
#pragma unroll
  for (int dt = 0; dt < kDh / 16; ++dt) wmma::fill_fragment(acc[dt], 0.f);
  for (int kt = 0; kt < col_tiles; ++kt) {
    FragA pa;
    wmma::load_matrix_sync(pa, half_strip + 16 * kt, geo.ldh);
#pragma unroll
    for (int dt = 0; dt < kDh / 16; ++dt) {
      FragB vb;
      wmma::load_matrix_sync(vb, vs + 16 * kt * kHeadLd + 16 * dt, kHeadLd);
      wmma::mma_sync(acc[dt], pa, vb, acc[dt]);
    }
  }
#pragma unroll
  for (int dt = 0; dt < kDh / 16; ++dt) wmma::store_matrix_sync(strip + 16 * dt, acc[dt], geo.lds, wmma::mem_row_major);
  __syncwarp();
  bf16* o = out + ray * tokens * width + head * kDh;
#pragma unroll
  for (int dt = 0; dt < kDh / 16; ++dt)
    store_tile_bf16(strip + 16 * dt, geo.lds, 1.f, o, width, r0, 16 * dt, tokens, lane);
}

// Column strips first: a warp takes keys [16c, 16c + 16) and, over the query tiles that see them,
// recomputes P and dS tile by tile, accumulating dV = P^T dO and dK = scale dS^T Q in registers and
// keeping dS in shared memory; then row strips: dQ = scale dS K.
// Two blocks per SM (shared memory allows it at L = 97): at most 128 registers per thread.
__global__ void __launch_bounds__(32 * kMaxTcWarps, 2)
    backward_bf16(const bf16* __restrict__ qkv, const bf16* __restrict__ out, const bf16* __restrict__ grad_out,
                  const float* __restrict__ lse, bf16* __restrict__ grad_qkv, int tokens, int heads, bool masked,
                  float scale) {
  const TcGeometry geo(tokens);
  const int64_t item = blockIdx.x;
  const int64_t ray = item / heads;
  const int head = int(item % heads);
  const int width = heads * kDh;
  const int64_t stride = 3 * int64_t(width);
  const bf16* src = qkv + ray * tokens * stride + head * kDh;
  const int64_t head_offset = ray * tokens * width + head * kDh;  // into out / grad_out

  extern __shared__ __align__(128) unsigned char smem_bytes[];
  bf16* qs = reinterpret_cast<bf16*>(smem_bytes);
  bf16* ks = qs + geo.padded * kHeadLd;
  bf16* vs = ks + geo.padded * kHeadLd;
  bf16* gs = vs + geo.padded * kHeadLd;   // dO
  bf16* dss = gs + geo.padded * kHeadLd;  // O first (kHeadLd apart), then dS (ldp apart)
  float* dvec = reinterpret_cast<float*>(smem_bytes + 4 * geo.head_bytes() + geo.square_bytes());
  float* lrow = dvec + geo.padded;
  const int warp = threadIdx.x / 32, lane = threadIdx.x % 32;
  float* tile = reinterpret_cast<float*>(smem_bytes + 4 * geo.head_bytes() + geo.square_bytes() +
                                         2 * geo.padded * sizeof(float) + warp * geo.tile_bytes());
  bf16* ptile = reinterpret_cast<bf16*>(tile + 16 * kTileLd);

  load_head_bf16(src, stride, tokens, geo.padded, qs);
  load_head_bf16(src + width, stride, tokens, geo.padded, ks);
  load_head_bf16(src + 2 * width, stride, tokens, geo.padded, vs);
  load_head_bf16(grad_out + head_offset, width, tokens, geo.padded, gs);
  load_head_bf16(out + head_offset, width, tokens, geo.padded, dss);
  for (int i = threadIdx.x; i < geo.padded; i += blockDim.x) lrow[i] = i < tokens ? lse[item * tokens + i] : 0.f;
  copy_async_wait();
  __syncthreads();
  // D_i = dO_i . O_i (0 on padded rows).
  for (int i = warp; i < geo.padded; i += geo.warps) {
    const float2 o2 = __bfloat1622float2(*reinterpret_cast<const __nv_bfloat162*>(dss + i * kHeadLd + 2 * lane));
    const float2 g2 = __bfloat1622float2(*reinterpret_cast<const __nv_bfloat162*>(gs + i * kHeadLd + 2 * lane));
    const float d = warp_sum(o2.x * g2.x + o2.y * g2.y);
    if (lane == 0) dvec[i] = d;
  }
  __syncthreads();

  bf16* gq = grad_qkv + ray * tokens * stride + head * kDh;
  bf16* gk = gq + width;
  bf16* gv = gq + 2 * width;

  for (int c = warp; c < geo.tiles; c += geo.warps) {
    const int c0 = 16 * c;
    FragC dv[kDh / 16], dk[kDh / 16];
#pragma unroll
    for (int dt = 0; dt < kDh / 16; ++dt) {
      wmma::fill_fragment(dv[dt], 0.f);
      wmma::fill_fragment(dk[dt], 0.f);
    }
    // Query tiles that see these keys: tile 0 (it holds the ray token), then first..tiles-1.
    const int first = masked && c > 1 ? c : 1;
    for (int qt = 0; qt < geo.tiles; qt = qt == 0 ? first : qt + 1) {
      const int q0 = 16 * qt;
      // S tile = Q_qt K_c^T  ->  P (8 values per lane, kept in registers).
      FragC acc;
      wmma::fill_fragment(acc, 0.f);
#pragma unroll
      for (int kk = 0; kk < kDh / 16; ++kk) {
        FragA qa;
        FragBT kb;
        wmma::load_matrix_sync(qa, qs + q0 * kHeadLd + 16 * kk, kHeadLd);
        wmma::load_matrix_sync(kb, ks + c0 * kHeadLd + 16 * kk, kHeadLd);
        wmma::mma_sync(acc, qa, kb, acc);
      }
      wmma::store_matrix_sync(tile, acc, kTileLd, wmma::mem_row_major);
      __syncwarp();
      float p[8];
#pragma unroll
      for (int e = 0; e < 8; ++e) {
        const int r = (lane + 32 * e) / 16, cc = (lane + 32 * e) % 16, i = q0 + r, j = c0 + cc;
        const int last = i < tokens ? last_column(i, tokens, masked) : -1;
        p[e] = j <= last ? expf(tile[r * kTileLd + cc] * scale - lrow[i]) : 0.f;
        ptile[r * kHalfTileLd + cc] = __float2bfloat16_rn(p[e]);
      }
      __syncwarp();
      // dP tile = dO_qt V_c^T  ->  dS = P (dP - D).
      wmma::fill_fragment(acc, 0.f);
#pragma unroll
      for (int kk = 0; kk < kDh / 16; ++kk) {
        FragA ga;
        FragBT vb;
        wmma::load_matrix_sync(ga, gs + q0 * kHeadLd + 16 * kk, kHeadLd);
        wmma::load_matrix_sync(vb, vs + c0 * kHeadLd + 16 * kk, kHeadLd);
        wmma::mma_sync(acc, ga, vb, acc);
      }
      wmma::store_matrix_sync(tile, acc, kTileLd, wmma::mem_row_major);
      __syncwarp();
#pragma unroll
      for (int e = 0; e < 8; ++e) {
        const int r = (lane + 32 * e) / 16, cc = (lane + 32 * e) % 16, i = q0 + r;
        dss[i * geo.ldp + c0 + cc] = __float2bfloat16_rn(p[e] * (tile[r * kTileLd + cc] - dvec[i]));
      }
      __syncwarp();
      // dV_c += P^T dO_qt;  dK_c += dS^T Q_qt.
      FragAT pt, st;
      wmma::load_matrix_sync(pt, ptile, kHalfTileLd);
      wmma::load_matrix_sync(st, dss + q0 * geo.ldp + c0, geo.ldp);
#pragma unroll
      for (int dt = 0; dt < kDh / 16; ++dt) {
        FragB gb, qb;
        wmma::load_matrix_sync(gb, gs + q0 * kHeadLd + 16 * dt, kHeadLd);
        wmma::mma_sync(dv[dt], pt, gb, dv[dt]);
        wmma::load_matrix_sync(qb, qs + q0 * kHeadLd + 16 * dt, kHeadLd);
        wmma::mma_sync(dk[dt], st, qb, dk[dt]);
      }
      __syncwarp();  // ptile and tile are rewritten by the next query tile
    }
#pragma unroll
    for (int dt = 0; dt < kDh / 16; ++dt) {
      wmma::store_matrix_sync(tile, dv[dt], kTileLd, wmma::mem_row_major);
      __syncwarp();
      store_tile_bf16(tile, kTileLd, 1.f, gv, stride, c0, 16 * dt, tokens, lane);
      __syncwarp();
      wmma::store_matrix_sync(tile, dk[dt], kTileLd, wmma::mem_row_major);
      __syncwarp();
      store_tile_bf16(tile, kTileLd, scale, gk, stride, c0, 16 * dt, tokens, lane);
      __syncwarp();
    }
  }
  __syncthreads();

  // Row strips: dQ = scale dS K over the key tiles each strip sees (all of them for tile 0).
  for (int t = warp; t < geo.tiles; t += geo.warps) {
    const int r0 = 16 * t;
    const int col_tiles = masked && t > 0 ? t + 1 : geo.tiles;
    FragC acc[kDh / 16];
#pragma unroll
    for (int dt = 0; dt < kDh / 16; ++dt) wmma::fill_fragment(acc[dt], 0.f);
    for (int kt = 0; kt < col_tiles; ++kt) {
      FragA da;
      wmma::load_matrix_sync(da, dss + r0 * geo.ldp + 16 * kt, geo.ldp);
#pragma unroll
      for (int dt = 0; dt < kDh / 16; ++dt) {
        FragB kb;
        wmma::load_matrix_sync(kb, ks + 16 * kt * kHeadLd + 16 * dt, kHeadLd);
        wmma::mma_sync(acc[dt], da, kb, acc[dt]);
      }
    }
#pragma unroll
    for (int dt = 0; dt < kDh / 16; ++dt) {
      wmma::store_matrix_sync(tile, acc[dt], kTileLd, wmma::mem_row_major);
      __syncwarp();
      store_tile_bf16(tile, kTileLd, scale, gq, stride, r0, 16 * dt, tokens, lane);
      __syncwarp();
    }
  }
}

// Shared memory beyond 48 KB must be granted per kernel before launch.
template <class Kernel>
cudaError_t grant_smem(Kernel kernel, size_t bytes) {
  return cudaFuncSetAttribute(kernel, cudaFuncAttributeMaxDynamicSharedMemorySize, int(bytes));
}

float softmax_scale() { return 1.f / sqrtf(float(kDh)); }

}  // namespace

bool ray_attention_shape_supported(const RayAttentionShape& shape) {
  return shape.batch >= 0 && shape.tokens >= 1 && shape.tokens <= kRayAttentionMaxTokens && shape.heads >= 1 &&
         shape.batch * shape.heads <= 0x7fffffff;
}

cudaError_t launch_ray_attention_forward(const float* qkv, float* out, float* lse, float* row0,
                                         const RayAttentionShape& shape, cudaStream_t stream) {
  if (!ray_attention_shape_supported(shape)) return cudaErrorInvalidValue;
  if (shape.batch == 0) return cudaSuccess;
  const size_t smem = fp32_forward_smem(shape.tokens);
  if (const cudaError_t e = grant_smem(forward_fp32, smem); e != cudaSuccess) return e;
  forward_fp32<<<unsigned(shape.batch * shape.heads), kFp32Threads, smem, stream>>>(
      qkv, out, lse, row0, shape.tokens, shape.heads, shape.masked, softmax_scale());
  return cudaGetLastError();
}

cudaError_t launch_ray_attention_forward(const __nv_bfloat16* qkv, __nv_bfloat16* out, float* lse, float* row0,
                                         const RayAttentionShape& shape, cudaStream_t stream) {
  if (!ray_attention_shape_supported(shape)) return cudaErrorInvalidValue;
  if (shape.batch == 0) return cudaSuccess;
  const TcGeometry geo(shape.tokens);
  const size_t smem = geo.forward_smem();
  if (const cudaError_t e = grant_smem(forward_bf16, smem); e != cudaSuccess) return e;
  forward_bf16<<<unsigned(shape.batch * shape.heads), 32 * geo.warps, smem, stream>>>(
      qkv, out, lse, row0, shape.tokens, shape.heads, shape.masked, softmax_scale());
  return cudaGetLastError();
}

cudaError_t launch_ray_attention_backward(const float* qkv, const float* out, const float* grad_out, const float* lse,
                                          float* grad_qkv, const RayAttentionShape& shape, cudaStream_t stream) {
  if (!ray_attention_shape_supported(shape)) return cudaErrorInvalidValue;
  if (shape.batch == 0) return cudaSuccess;
  const size_t smem = fp32_backward_smem(shape.tokens);
  if (const cudaError_t e = grant_smem(backward_fp32, smem); e != cudaSuccess) return e;
  backward_fp32<<<unsigned(shape.batch * shape.heads), kFp32Threads, smem, stream>>>(
      qkv, out, grad_out, lse, grad_qkv, shape.tokens, shape.heads, shape.masked, softmax_scale());
  return cudaGetLastError();
}

cudaError_t launch_ray_attention_backward(const __nv_bfloat16* qkv, const __nv_bfloat16* out,
                                          const __nv_bfloat16* grad_out, const float* lse, __nv_bfloat16* grad_qkv,
                                          const RayAttentionShape& shape, cudaStream_t stream) {
  if (!ray_attention_shape_supported(shape)) return cudaErrorInvalidValue;
  if (shape.batch == 0) return cudaSuccess;
  const TcGeometry geo(shape.tokens);
  const size_t smem = geo.backward_smem();
  if (const cudaError_t e = grant_smem(backward_bf16, smem); e != cudaSuccess) return e;
  backward_bf16<<<unsigned(shape.batch * shape.heads), 32 * geo.warps, smem, stream>>>(
      qkv, out, grad_out, lse, grad_qkv, shape.tokens, shape.heads, shape.masked, softmax_scale());
  return cudaGetLastError();
}

}  // namespace ablenerf::kernels
