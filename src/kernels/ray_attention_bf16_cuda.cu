// Fused self-attention over the tokens of one ray on tensor cores (bf16 inputs, fp32 accumulation):
// the design is described at the top of ray_attention_fp32_cuda.cu, the layouts in
// ray_attention_launch.h.
#include <mma.h>

#include "kernels/ray_attention_common.cuh"

namespace ablenerf::kernels {

namespace {

using namespace ray_attention_detail;

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

}  // namespace

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
