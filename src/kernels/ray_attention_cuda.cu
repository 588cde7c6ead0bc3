// Fused self-attention over the tokens of one ray (forward and backward), read straight from the
// packed projection. One thread block per (ray, head): the head's Q, K and V (at most 128 x 64)
// sit in shared memory, the scores and the softmax never leave the chip, and the ray mask skips
// the blocked half of every product. See ray_attention_launch.h for the layouts.
//
// Two implementations, one per input type:
//  * fp32: CUDA cores, every thread computing 4 x 4 blocks of each product from shared memory;
//  * bf16: tensor cores (WMMA 16 x 16 x 16, bf16 -> fp32) on tiles padded to 16 rows, one warp
//    per 16-row strip of the scores, so that the softmax needs no block-wide barrier.
#include <cuda_bf16.h>
#include <math_constants.h>
#include <mma.h>

#include "ray_attention_launch.h"

namespace ablenerf::kernels {

namespace {

constexpr int kDh = kRayAttentionHeadDim;
constexpr unsigned kFullMask = 0xffffffffu;

// The last column row i may attend to.
__device__ __forceinline__ int last_column(int i, int tokens, bool masked) { return masked && i > 0 ? i : tokens - 1; }

__device__ __forceinline__ float warp_max(float x) {
  for (int offset = 16; offset > 0; offset >>= 1) x = fmaxf(x, __shfl_xor_sync(kFullMask, x, offset));
  return x;
}

__device__ __forceinline__ float warp_sum(float x) {
  for (int offset = 16; offset > 0; offset >>= 1) x += __shfl_xor_sync(kFullMask, x, offset);
  return x;
}

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

// Of the backward: Q, K, V, dO, the probabilities / dS, and two per-row vectors.
inline size_t fp32_backward_smem(int tokens) {
  const size_t p = fp32_padded(tokens);
  return (4 * p * kHeadStride + p * (p + 1) + 2 * p) * sizeof(float);
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

// Rows [0, padded) of a head's (tokens x 64) matrix, rows `row_stride` apart, into dst
// (kHeadStride apart); rows >= tokens are zero.
__device__ void load_head_fp32(const float* __restrict__ src, int64_t row_stride, int tokens, int padded,
                               float* __restrict__ dst) {
  for (int e = threadIdx.x; e < padded * kDh; e += blockDim.x) {
    const int i = e / kDh, d = e % kDh;
    dst[i * kHeadStride + d] = i < tokens ? src[i * row_stride + d] : 0.f;
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
  float* g = v + padded * kHeadStride;  // dO
  float* p = g + padded * kHeadStride;  // P, then dS in place
  float* dvec = p + padded * ls;        // D_i = dO_i . O_i
  float* lrow = dvec + padded;          // the forward's log-sum-exp
  load_head_fp32(src, stride, tokens, padded, q);
  load_head_fp32(src + width, stride, tokens, padded, k);
  load_head_fp32(src + 2 * width, stride, tokens, padded, v);
  load_head_fp32(grad_out + head_offset, width, tokens, padded, g);
  const int warp = threadIdx.x / 32, lane = threadIdx.x % 32, warps = blockDim.x / 32;
  for (int i = warp; i < padded; i += warps) {
    float d = 0.f;
    if (i < tokens) {
      const float* orow = out + head_offset + int64_t(i) * width;
      const float* grow = grad_out + head_offset + int64_t(i) * width;
      for (int c = lane; c < kDh; c += 32) d += orow[c] * grow[c];
    }
    d = warp_sum(d);
    if (lane == 0) {
      dvec[i] = d;
      lrow[i] = i < tokens ? lse[item * tokens + i] : 0.f;
    }
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
          for (int c = 0; c < 4; ++c)
            p[i * ls + j0 + c] = j0 + c <= last ? expf(acc[r][c] * scale - lrow[i]) : 0.f;
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

constexpr int kHeadLd = kDh + 8;   // bf16 row stride of the (rows x 64) operands in shared memory
constexpr int kTileLd = 16 + 4;    // fp32 row stride of a warp's 16 x 16 tile
constexpr int kMaxTcWarps = 8;

// The geometry every bf16 kernel and its launch agree on. Row strides are multiples of 8 bf16 /
// 4 floats (WMMA's rule) and every region starts 32-byte aligned (WMMA's pointer rule).
struct TcGeometry {
  int tiles;    // 16-row tiles covering the tokens
  int padded;   // 16 * tiles
  int ldp;      // bf16 row stride of the (padded x padded) P and dS of the backward
  int lds;      // fp32 row stride of a warp's 16-row strip (scores, then 16 x 64 results)
  int warps;    // warps per block, one 16-row strip each at a time
  __host__ __device__ explicit TcGeometry(int tokens)
      : tiles((tokens + 15) / 16),
        padded(16 * tiles),
        ldp(padded + 8),
        lds((padded > kDh ? padded : kDh) + 4),
        warps(tiles < kMaxTcWarps ? tiles : kMaxTcWarps) {}
  __host__ __device__ size_t head_bytes() const { return size_t(padded) * kHeadLd * sizeof(bf16); }
  __host__ __device__ size_t strip_bytes() const { return size_t(16) * lds * sizeof(float); }
  __host__ __device__ size_t forward_smem() const { return 2 * head_bytes() + warps * strip_bytes(); }
  __host__ __device__ size_t square_bytes() const { return size_t(padded) * ldp * sizeof(bf16); }
  __host__ __device__ size_t backward_smem() const {
    return 4 * head_bytes() + 2 * square_bytes() + 2 * padded * sizeof(float) +
           warps * (strip_bytes() + 16 * kTileLd * sizeof(float));
  }
};

// Rows [row_begin, row_end) of a head's (tokens x 64) bf16 matrix into dst (row row_begin at
// dst, kHeadLd apart), 16 bytes at a time by threads lane, lane + lanes, ...; rows >= tokens zero.
__device__ __forceinline__ void load_head_bf16(const bf16* __restrict__ src, int64_t row_stride, int tokens,
                                               int row_begin, int row_end, bf16* __restrict__ dst, int lane,
                                               int lanes) {
  const int chunks = (row_end - row_begin) * (kDh / 8);
  for (int e = lane; e < chunks; e += lanes) {
    const int r = e / (kDh / 8), c = (e % (kDh / 8)) * 8, i = row_begin + r;
    uint4 x = make_uint4(0u, 0u, 0u, 0u);
    if (i < tokens) x = *reinterpret_cast<const uint4*>(src + i * row_stride + c);
    *reinterpret_cast<uint4*>(dst + r * kHeadLd + c) = x;
  }
}

// A warp's 16 x 64 fp32 results (strip, row stride lds) times `factor`, as bf16 into rows
// [row0, row0 + 16) of dst (rows row_stride apart), skipping rows >= tokens.
__device__ __forceinline__ void store_strip_bf16(const float* strip, int lds, float factor, bf16* __restrict__ dst,
                                                 int64_t row_stride, int row0, int tokens, int lane) {
  for (int e = lane; e < 16 * (kDh / 8); e += 32) {
    const int r = e / (kDh / 8), c = (e % (kDh / 8)) * 8, i = row0 + r;
    if (i >= tokens) continue;
    const float* x = strip + r * lds + c;
    union {
      uint4 u;
      __nv_bfloat162 h[4];
    } pack;
#pragma unroll
    for (int t = 0; t < 4; ++t) pack.h[t] = __floats2bfloat162_rn(x[2 * t] * factor, x[2 * t + 1] * factor);
    *reinterpret_cast<uint4*>(dst + i * row_stride + c) = pack.u;
  }
}

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
  load_head_bf16(src + width, stride, tokens, 0, geo.padded, ks, threadIdx.x, blockDim.x);
  load_head_bf16(src + 2 * width, stride, tokens, 0, geo.padded, vs, threadIdx.x, blockDim.x);
  __syncthreads();

  bf16* pstrip = reinterpret_cast<bf16*>(strip);  // P written over the scores, row by row
  const int ldp = 2 * geo.lds;
  bf16* o = out + ray * tokens * width + head * kDh;
  for (int t = warp; t < geo.tiles; t += geo.warps) {
    const int r0 = 16 * t;
    const int col_tiles = masked && t > 0 ? t + 1 : geo.tiles;  // tiles right of the diagonal are blocked
    const int cols = 16 * col_tiles;

    // This strip's Q, staged through the warp's scratch into fragments.
    load_head_bf16(src, stride, tokens, r0, r0 + 16, pstrip, lane, 32);
    __syncwarp();
    FragA qa[kDh / 16];
#pragma unroll
    for (int kk = 0; kk < kDh / 16; ++kk) wmma::load_matrix_sync(qa[kk], pstrip + 16 * kk, kHeadLd);
    __syncwarp();

    // Scores of the strip (unscaled).
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

    // Softmax of each row in fp32; P as bf16 over the row's own bytes (read fully before written).
    for (int r = 0; r < 16; ++r) {
      const int i = r0 + r;
      const int last = i < tokens ? last_column(i, tokens, masked) : -1;
      const float* srow = strip + r * geo.lds;
      float x[kRayAttentionMaxTokens / 32];
      float m = -CUDART_INF_F;
#pragma unroll
      for (int c = 0; c < kRayAttentionMaxTokens / 32; ++c) {
        const int j = lane + 32 * c;
        x[c] = j <= last ? srow[j] * scale : -CUDART_INF_F;
        m = fmaxf(m, x[c]);
      }
      m = warp_max(m);
      float sum = 0.f;
#pragma unroll
      for (int c = 0; c < kRayAttentionMaxTokens / 32; ++c) {
        const int j = lane + 32 * c;
        x[c] = j <= last ? expf(x[c] - m) : 0.f;
        sum += x[c];
      }
      sum = warp_sum(sum);
      __syncwarp();
      const float inv = last >= 0 ? 1.f / sum : 0.f;
#pragma unroll
      for (int c = 0; c < kRayAttentionMaxTokens / 32; ++c) {
        const int j = lane + 32 * c;
        if (j < cols) pstrip[r * ldp + j] = __float2bfloat16_rn(x[c] * inv);
        if (i == 0 && j < tokens) row0[item * tokens + j] = x[c] * inv;
      }
      if (last >= 0 && lane == 0) lse[item * tokens + i] = m + logf(sum);
    }
    __syncwarp();

    // O = P V over the visible key tiles.
    FragC acc[kDh / 16];
#pragma unroll
    for (int dt = 0; dt < kDh / 16; ++dt) wmma::fill_fragment(acc[dt], 0.f);
    for (int kt = 0; kt < col_tiles; ++kt) {
      FragA pa;
      wmma::load_matrix_sync(pa, pstrip + 16 * kt, ldp);
#pragma unroll
      for (int dt = 0; dt < kDh / 16; ++dt) {
        FragB vb;
        wmma::load_matrix_sync(vb, vs + 16 * kt * kHeadLd + 16 * dt, kHeadLd);
        wmma::mma_sync(acc[dt], pa, vb, acc[dt]);
      }
    }
    __syncwarp();
#pragma unroll
    for (int dt = 0; dt < kDh / 16; ++dt) wmma::store_matrix_sync(strip + 16 * dt, acc[dt], geo.lds, wmma::mem_row_major);
    __syncwarp();
    store_strip_bf16(strip, geo.lds, 1.f, o, width, r0, tokens, lane);
    __syncwarp();
  }
}

__global__ void __launch_bounds__(32 * kMaxTcWarps)
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
  bf16* gs = vs + geo.padded * kHeadLd;    // dO
  bf16* ps = gs + geo.padded * kHeadLd;    // P (padded x ldp)
  bf16* dss = ps + geo.padded * geo.ldp;   // dS
  float* dvec = reinterpret_cast<float*>(dss + geo.padded * geo.ldp);
  float* lrow = dvec + geo.padded;
  const int warp = threadIdx.x / 32, lane = threadIdx.x % 32;
  float* strip = reinterpret_cast<float*>(smem_bytes + 4 * geo.head_bytes() + 2 * geo.square_bytes() +
                                          2 * geo.padded * sizeof(float) +
                                          warp * (geo.strip_bytes() + 16 * kTileLd * sizeof(float)));
  float* tile = strip + 16 * geo.lds;

  load_head_bf16(src, stride, tokens, 0, geo.padded, qs, threadIdx.x, blockDim.x);
  load_head_bf16(src + width, stride, tokens, 0, geo.padded, ks, threadIdx.x, blockDim.x);
  load_head_bf16(src + 2 * width, stride, tokens, 0, geo.padded, vs, threadIdx.x, blockDim.x);
  load_head_bf16(grad_out + head_offset, width, tokens, 0, geo.padded, gs, threadIdx.x, blockDim.x);
  for (int i = warp; i < geo.padded; i += geo.warps) {
    float d = 0.f;
    if (i < tokens) {
      const bf16* orow = out + head_offset + int64_t(i) * width;
      const bf16* grow = grad_out + head_offset + int64_t(i) * width;
      for (int c = lane; c < kDh; c += 32) d += __bfloat162float(orow[c]) * __bfloat162float(grow[c]);
    }
    d = warp_sum(d);
    if (lane == 0) {
      dvec[i] = d;
      lrow[i] = i < tokens ? lse[item * tokens + i] : 0.f;
    }
  }
  __syncthreads();

  bf16* gq = grad_qkv + ray * tokens * stride + head * kDh;
  bf16* gk = gq + width;
  bf16* gv = gq + 2 * width;

  // Row strips: P, dS and dQ of rows [16t, 16t + 16).
  for (int t = warp; t < geo.tiles; t += geo.warps) {
    const int r0 = 16 * t;
    const int col_tiles = masked && t > 0 ? t + 1 : geo.tiles;
    const int cols = 16 * col_tiles;
    {
      FragA qa[kDh / 16];
#pragma unroll
      for (int kk = 0; kk < kDh / 16; ++kk) wmma::load_matrix_sync(qa[kk], qs + r0 * kHeadLd + 16 * kk, kHeadLd);
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
    }
    __syncwarp();
    // P = exp(scale S - lse) where visible, else 0: fp32 in the strip, bf16 in ps (whole rows).
    for (int r = 0; r < 16; ++r) {
      const int i = r0 + r;
      const int last = i < tokens ? last_column(i, tokens, masked) : -1;
      const float li = lrow[i];
      float* srow = strip + r * geo.lds;
      for (int j = lane; j < geo.padded; j += 32) {
        const float pv = j <= last ? expf(srow[j] * scale - li) : 0.f;
        if (j < cols) srow[j] = pv;
        ps[i * geo.ldp + j] = __float2bfloat16_rn(pv);
        if (j >= cols) dss[i * geo.ldp + j] = __float2bfloat16_rn(0.f);
      }
    }
    __syncwarp();
    // dS = P (dP - D), dP = dO V^T, one 16 x 16 tile at a time.
    {
      FragA ga[kDh / 16];
#pragma unroll
      for (int kk = 0; kk < kDh / 16; ++kk) wmma::load_matrix_sync(ga[kk], gs + r0 * kHeadLd + 16 * kk, kHeadLd);
      for (int ct = 0; ct < col_tiles; ++ct) {
        FragC acc;
        wmma::fill_fragment(acc, 0.f);
#pragma unroll
        for (int kk = 0; kk < kDh / 16; ++kk) {
          FragBT vb;
          wmma::load_matrix_sync(vb, vs + 16 * ct * kHeadLd + 16 * kk, kHeadLd);
          wmma::mma_sync(acc, ga[kk], vb, acc);
        }
        wmma::store_matrix_sync(tile, acc, kTileLd, wmma::mem_row_major);
        __syncwarp();
        for (int e = lane; e < 256; e += 32) {
          const int r = e / 16, c = e % 16, i = r0 + r, j = 16 * ct + c;
          const float ds = strip[r * geo.lds + j] * (tile[r * kTileLd + c] - dvec[i]);
          dss[i * geo.ldp + j] = __float2bfloat16_rn(ds);
        }
        __syncwarp();
      }
    }
    // dQ = scale dS K.
    {
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
      __syncwarp();
#pragma unroll
      for (int dt = 0; dt < kDh / 16; ++dt)
        wmma::store_matrix_sync(strip + 16 * dt, acc[dt], geo.lds, wmma::mem_row_major);
      __syncwarp();
      store_strip_bf16(strip, geo.lds, scale, gq, stride, r0, tokens, lane);
      __syncwarp();
    }
  }
  __syncthreads();

  // Column strips: dV = P^T dO and dK = scale dS^T Q for keys [16t, 16t + 16), summed over the
  // query tiles that see them (tile 0, holding the ray token, and tiles t.. when masked).
  for (int t = warp; t < geo.tiles; t += geo.warps) {
    const int c0 = 16 * t;
    FragC dv[kDh / 16], dk[kDh / 16];
#pragma unroll
    for (int dt = 0; dt < kDh / 16; ++dt) {
      wmma::fill_fragment(dv[dt], 0.f);
      wmma::fill_fragment(dk[dt], 0.f);
    }
    const int first = masked && t > 1 ? t : 1;  // query tiles: 0, then first..tiles-1
    for (int qt = 0; qt < geo.tiles; qt = qt == 0 ? first : qt + 1) {
      FragAT pt, dt_;
      wmma::load_matrix_sync(pt, ps + 16 * qt * geo.ldp + c0, geo.ldp);
      wmma::load_matrix_sync(dt_, dss + 16 * qt * geo.ldp + c0, geo.ldp);
#pragma unroll
      for (int dt = 0; dt < kDh / 16; ++dt) {
        FragB gb, qb;
        wmma::load_matrix_sync(gb, gs + 16 * qt * kHeadLd + 16 * dt, kHeadLd);
        wmma::mma_sync(dv[dt], pt, gb, dv[dt]);
        wmma::load_matrix_sync(qb, qs + 16 * qt * kHeadLd + 16 * dt, kHeadLd);
        wmma::mma_sync(dk[dt], dt_, qb, dk[dt]);
      }
    }
#pragma unroll
    for (int dt = 0; dt < kDh / 16; ++dt) wmma::store_matrix_sync(strip + 16 * dt, dv[dt], geo.lds, wmma::mem_row_major);
    __syncwarp();
    store_strip_bf16(strip, geo.lds, 1.f, gv, stride, c0, tokens, lane);
    __syncwarp();
#pragma unroll
    for (int dt = 0; dt < kDh / 16; ++dt) wmma::store_matrix_sync(strip + 16 * dt, dk[dt], geo.lds, wmma::mem_row_major);
    __syncwarp();
    store_strip_bf16(strip, geo.lds, scale, gk, stride, c0, tokens, lane);
    __syncwarp();
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
