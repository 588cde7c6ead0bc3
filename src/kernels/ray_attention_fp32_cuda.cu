// Fused self-attention over the tokens of one ray (forward and backward), read straight from the
// packed projection: fp32 here, bf16 in ray_attention_bf16_cuda.cu. One thread block per (ray, head): the head's Q, K
// and V (at most 128 x 64) sit in shared memory, the scores and the softmax never leave the chip, and the ray mask
// skips the blocked half of every product. See ray_attention_launch.h for the layouts.
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
#include "kernels/ray_attention_common.cuh"

namespace ablenerf::kernels {

namespace {

using namespace ray_attention_detail;

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

}  // namespace ablenerf::kernels
