// Fused residual add + LayerNorm, forward and backward (declarations and conventions in
// residual_layer_norm_launch.h). One warp per row: lane l holds the row's columns l, l + 32, ...
// in registers (6 values per lane at width 192), so every load and store of a warp is one
// contiguous run of 32 values, and the row's sums are warp shuffles without shared memory.
#include "kernels/cuda_common.cuh"
#include "kernels/residual_layer_norm_launch.h"

#include <type_traits>

namespace ablenerf {

namespace {

using cuda_detail::kWarp;
using cuda_detail::load;
using cuda_detail::store;
using cuda_detail::warp_sum;

constexpr int kRowsPerBlock = 8;  // warps per block, one row each
constexpr int kThreads = kWarp * kRowsPerBlock;
// The backward's blocks loop over rows and leave one partial [dgamma | dbeta] each; a fixed cap
// (not the device's SM count) keeps the summation order, hence the result, the same everywhere.
constexpr int kMaxBackwardBlocks = 1024;

// kMaxPerLane: the register arrays' size, a power of two >= width / 32 (the kernels are compiled
// for 2, 4, 8, 16 and 32 and guard the unused tail of the array at run time).
template <class T, int kMaxPerLane>
__global__ void __launch_bounds__(kThreads)
    forward_kernel(const T* __restrict__ x, const T* __restrict__ r, const float* __restrict__ gamma,
                   const float* __restrict__ beta, int64_t rows, int width, float eps, T* __restrict__ y,
                   float* __restrict__ mean_out, float* __restrict__ rstd_out) {
  const int lane = threadIdx.x % kWarp;
  const int64_t row = int64_t(blockIdx.x) * kRowsPerBlock + threadIdx.x / kWarp;
  if (row >= rows) return;  // the whole warp leaves together: no shuffle misses a lane
  const int per_lane = width / kWarp;
  const int64_t base = row * width;
  float s[kMaxPerLane];
  float sum = 0.f;
#pragma unroll
  for (int i = 0; i < kMaxPerLane; ++i) {
    s[i] = 0.f;
    if (i < per_lane) {
      const int64_t j = base + i * kWarp + lane;
      s[i] = load(x, j) + load(r, j);
      sum += s[i];
    }
  }
  // Divisions, not products with 1 / width: a constant row then has its exact mean, zero variance.
  const float mean = warp_sum(sum) / float(width);
  // Two passes over the registers: the variance from centred values, no cancellation.
  float squares = 0.f;
#pragma unroll
  for (int i = 0; i < kMaxPerLane; ++i) {
    if (i < per_lane) {
      const float d = s[i] - mean;
      squares += d * d;
    }
  }
  const float rstd = rsqrtf(warp_sum(squares) / float(width) + eps);
#pragma unroll
  for (int i = 0; i < kMaxPerLane; ++i) {
    if (i < per_lane) {
      const int c = i * kWarp + lane;
      store(y, base + c, (s[i] - mean) * rstd * gamma[c] + beta[c]);
    }
  }
  if (lane == 0) {
    mean_out[row] = mean;
    rstd_out[row] = rstd;
  }
}

// With xhat = (s - mean) * rstd and g = dy * gamma (per row, n = width):
//   ds = rstd * (g - mean(g) - xhat * mean(g * xhat)),  dgamma = sum_rows dy * xhat,  dbeta = sum_rows dy.
// s is recomputed from x and r (exactly the forward's float sum). Each block walks rows
// blockIdx.x * 8 + warp, + gridDim.x * 8, ...; its warps' column sums meet in shared memory in warp
// order and leave the block as one row of `partial` (gridDim.x rows of 2 * width floats).
template <class T, int kMaxPerLane>
__global__ void __launch_bounds__(kThreads)
    backward_kernel(const T* __restrict__ dy, const T* __restrict__ x, const T* __restrict__ r,
                    const float* __restrict__ gamma, const float* __restrict__ mean, const float* __restrict__ rstd,
                    int64_t rows, int width, T* __restrict__ ds, float* __restrict__ partial) {
  const int warp = threadIdx.x / kWarp, lane = threadIdx.x % kWarp;
  const int per_lane = width / kWarp;
  float gam[kMaxPerLane], dgamma[kMaxPerLane], dbeta[kMaxPerLane];
#pragma unroll
  for (int i = 0; i < kMaxPerLane; ++i) {
    gam[i] = i < per_lane ? gamma[i * kWarp + lane] : 0.f;
    dgamma[i] = 0.f;
    dbeta[i] = 0.f;
  }
  for (int64_t row = int64_t(blockIdx.x) * kRowsPerBlock + warp; row < rows;
       row += int64_t(gridDim.x) * kRowsPerBlock) {
    const float mu = mean[row], rs = rstd[row];
    const int64_t base = row * width;
    float xhat[kMaxPerLane], g[kMaxPerLane];
    float sum_g = 0.f, sum_gx = 0.f;
#pragma unroll
    for (int i = 0; i < kMaxPerLane; ++i) {
      xhat[i] = 0.f;
      g[i] = 0.f;
      if (i < per_lane) {
        const int64_t j = base + i * kWarp + lane;
        const float d = load(dy, j);
        xhat[i] = (load(x, j) + load(r, j) - mu) * rs;
        g[i] = d * gam[i];
        sum_g += g[i];
        sum_gx += g[i] * xhat[i];
        dgamma[i] += d * xhat[i];
        dbeta[i] += d;
      }
    }
    const float mean_g = warp_sum(sum_g) / float(width), mean_gx = warp_sum(sum_gx) / float(width);
#pragma unroll
    for (int i = 0; i < kMaxPerLane; ++i) {
      if (i < per_lane) store(ds, base + i * kWarp + lane, rs * (g[i] - mean_g - xhat[i] * mean_gx));
    }
  }
  // The block's column sums: warp 0's values, then warp 1's added, ... (a fixed order).
  __shared__ float block_sums[2 * kResidualLayerNormMaxWidth];
  for (int c = threadIdx.x; c < 2 * width; c += blockDim.x) block_sums[c] = 0.f;
  __syncthreads();
  for (int w = 0; w < kRowsPerBlock; ++w) {
    if (warp == w) {
#pragma unroll
      for (int i = 0; i < kMaxPerLane; ++i) {
        if (i < per_lane) {
          const int c = i * kWarp + lane;
          block_sums[c] += dgamma[i];
          block_sums[width + c] += dbeta[i];
        }
      }
    }
    __syncthreads();
  }
  float* out = partial + int64_t(blockIdx.x) * 2 * width;
  for (int c = threadIdx.x; c < 2 * width; c += blockDim.x) out[c] = block_sums[c];
}

int forward_blocks(int64_t rows) { return int((rows + kRowsPerBlock - 1) / kRowsPerBlock); }
int backward_blocks(int64_t rows) {
  const int64_t wanted = (rows + kRowsPerBlock - 1) / kRowsPerBlock;
  return int(wanted < kMaxBackwardBlocks ? wanted : kMaxBackwardBlocks);
}

// Calls launch(std::integral_constant<int, kMaxPerLane>) for the smallest compiled size that holds
// width / 32 values per lane.
template <class Launch>
cudaError_t dispatch_width(int width, const Launch& launch) {
  if (!residual_layer_norm_width_supported(width)) return cudaErrorInvalidValue;
  const int per_lane = width / kWarp;
  if (per_lane <= 2) return launch(std::integral_constant<int, 2>());
  if (per_lane <= 4) return launch(std::integral_constant<int, 4>());
  if (per_lane <= 8) return launch(std::integral_constant<int, 8>());
  if (per_lane <= 16) return launch(std::integral_constant<int, 16>());
  return launch(std::integral_constant<int, 32>());
}

template <class T>
cudaError_t forward(const T* x, const T* r, const float* gamma, const float* beta, int64_t rows, int width, float eps,
                    T* y, float* mean, float* rstd, cudaStream_t stream) {
  return dispatch_width(width, [&](auto max_per_lane) {
    if (rows > 0)
      forward_kernel<T, decltype(max_per_lane)::value>
          <<<forward_blocks(rows), kThreads, 0, stream>>>(x, r, gamma, beta, rows, width, eps, y, mean, rstd);
    return cudaGetLastError();
  });
}

template <class T>
cudaError_t backward(const T* dy, const T* x, const T* r, const float* gamma, const float* mean, const float* rstd,
                     int64_t rows, int width, T* ds, float* dgb, float* workspace, cudaStream_t stream) {
  return dispatch_width(width, [&](auto max_per_lane) {
    const int blocks = backward_blocks(rows);
    if (blocks > 0)
      backward_kernel<T, decltype(max_per_lane)::value>
          <<<blocks, kThreads, 0, stream>>>(dy, x, r, gamma, mean, rstd, rows, width, ds, workspace);
    // No rows: zero blocks sum to zero gradients.
    cuda_detail::launch_column_sums(workspace, blocks, 2 * width, dgb, stream);
    return cudaGetLastError();
  });
}

}  // namespace

cudaError_t launch_residual_layer_norm_forward(const float* x, const float* r, const float* gamma, const float* beta,
                                               int64_t rows, int width, float eps, float* y, float* mean, float* rstd,
                                               cudaStream_t stream) {
  return forward(x, r, gamma, beta, rows, width, eps, y, mean, rstd, stream);
}

cudaError_t launch_residual_layer_norm_forward(const __nv_bfloat16* x, const __nv_bfloat16* r, const float* gamma,
                                               const float* beta, int64_t rows, int width, float eps, __nv_bfloat16* y,
                                               float* mean, float* rstd, cudaStream_t stream) {
  return forward(x, r, gamma, beta, rows, width, eps, y, mean, rstd, stream);
}

size_t residual_layer_norm_backward_workspace(int64_t rows, int width) {
  return size_t(backward_blocks(rows)) * 2 * size_t(width);
}

cudaError_t launch_residual_layer_norm_backward(const float* dy, const float* x, const float* r, const float* gamma,
                                                const float* mean, const float* rstd, int64_t rows, int width,
                                                float* ds, float* dgb, float* workspace, cudaStream_t stream) {
  return backward(dy, x, r, gamma, mean, rstd, rows, width, ds, dgb, workspace, stream);
}

cudaError_t launch_residual_layer_norm_backward(const __nv_bfloat16* dy, const __nv_bfloat16* x, const __nv_bfloat16* r,
                                                const float* gamma, const float* mean, const float* rstd, int64_t rows,
                                                int width, __nv_bfloat16* ds, float* dgb, float* workspace,
                                                cudaStream_t stream) {
  return backward(dy, x, r, gamma, mean, rstd, rows, width, ds, dgb, workspace, stream);
}

}  // namespace ablenerf
