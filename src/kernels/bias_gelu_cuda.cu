// Fused bias + exact (erf) GELU, forward and backward (declarations and conventions in
// bias_gelu_launch.h). Blocks of 64 columns x 4 rows: each thread keeps one column (its bias in a
// register) and walks rows, so a warp touches 32 consecutive values of a row, and in backward the
// thread adds up its column's dx as it goes: one partial sum per (block row, thread row) that a
// second small kernel adds up column by column in a fixed order.
#include "kernels/bias_gelu_launch.h"
#include "kernels/cuda_common.cuh"

namespace ablenerf {

namespace {

using cuda_detail::load;
using cuda_detail::store;

constexpr int kCols = 64;  // columns per block (blockDim.x)
constexpr int kRows = 4;   // rows per block step (blockDim.y)
// Block rows: each of the forward's covers a few rows; the backward's are capped at a fixed count
// (independent of the device) so that the partial sums and their order are the same everywhere.
constexpr int kMaxForwardBlockRows = 16384;
constexpr int kMaxBackwardBlockRows = 256;

constexpr float kSqrtHalf = 0.70710678118654752440f;      // 1 / sqrt(2)
constexpr float kInvSqrtTwoPi = 0.39894228040143267794f;  // 1 / sqrt(2 pi)

__device__ __forceinline__ float gelu(float z) { return 0.5f * z * (1.f + erff(z * kSqrtHalf)); }

// d/dz [z * Phi(z)] = Phi(z) + z * phi(z).
__device__ __forceinline__ float gelu_grad(float z) {
  const float cdf = 0.5f * (1.f + erff(z * kSqrtHalf));
  const float pdf = kInvSqrtTwoPi * expf(-0.5f * z * z);
  return cdf + z * pdf;
}

template <class T>
__global__ void __launch_bounds__(kCols* kRows)
    forward_kernel(const T* __restrict__ x, const float* __restrict__ b, int64_t rows, int cols, T* __restrict__ y) {
  const int c = blockIdx.x * kCols + threadIdx.x;
  if (c >= cols) return;
  const float bias = b[c];
  for (int64_t row = int64_t(blockIdx.y) * kRows + threadIdx.y; row < rows; row += int64_t(gridDim.y) * kRows) {
    const int64_t i = row * cols + c;
    store(y, i, gelu(load(x, i) + bias));
  }
}

// partial: (gridDim.y * kRows, cols); row p holds the sums over the rows that thread row p walked.
template <class T>
__global__ void __launch_bounds__(kCols* kRows)
    backward_kernel(const T* __restrict__ dy, const T* __restrict__ x, const float* __restrict__ b, int64_t rows,
                    int cols, T* __restrict__ dx, float* __restrict__ partial) {
  const int c = blockIdx.x * kCols + threadIdx.x;
  if (c >= cols) return;
  const float bias = b[c];
  const int64_t first = int64_t(blockIdx.y) * kRows + threadIdx.y;
  float sum = 0.f;
  for (int64_t row = first; row < rows; row += int64_t(gridDim.y) * kRows) {
    const int64_t i = row * cols + c;
    const float g = load(dy, i) * gelu_grad(load(x, i) + bias);
    store(dx, i, g);
    sum += g;
  }
  partial[first * cols + c] = sum;
}

int column_blocks(int cols) { return (cols + kCols - 1) / kCols; }
int block_rows(int64_t rows, int cap) {
  const int64_t wanted = (rows + kRows - 1) / kRows;
  return int(wanted < cap ? wanted : cap);
}

template <class T>
cudaError_t forward(const T* x, const float* b, int64_t rows, int cols, T* y, cudaStream_t stream) {
  if (cols < 0 || rows < 0) return cudaErrorInvalidValue;
  if (rows > 0 && cols > 0) {
    const dim3 grid(column_blocks(cols), block_rows(rows, kMaxForwardBlockRows)), block(kCols, kRows);
    forward_kernel<T><<<grid, block, 0, stream>>>(x, b, rows, cols, y);
  }
  return cudaGetLastError();
}

template <class T>
cudaError_t backward(const T* dy, const T* x, const float* b, int64_t rows, int cols, T* dx, float* db,
                     float* workspace, cudaStream_t stream) {
  if (cols < 0 || rows < 0) return cudaErrorInvalidValue;
  const int parts = block_rows(rows, kMaxBackwardBlockRows) * kRows;
  if (rows > 0 && cols > 0) {
    const dim3 grid(column_blocks(cols), parts / kRows), block(kCols, kRows);
    backward_kernel<T><<<grid, block, 0, stream>>>(dy, x, b, rows, cols, dx, workspace);
  }
  // No rows: zero partial rows sum to a zero gradient. Thread rows past the last row wrote zeros.
  cuda_detail::launch_column_sums(workspace, parts, cols, db, stream);
  return cudaGetLastError();
}

}  // namespace

cudaError_t launch_bias_gelu_forward(const float* x, const float* b, int64_t rows, int cols, float* y,
                                     cudaStream_t stream) {
  return forward(x, b, rows, cols, y, stream);
}

cudaError_t launch_bias_gelu_forward(const __nv_bfloat16* x, const float* b, int64_t rows, int cols, __nv_bfloat16* y,
                                     cudaStream_t stream) {
  return forward(x, b, rows, cols, y, stream);
}

size_t bias_gelu_backward_workspace(int64_t rows, int cols) {
  return size_t(block_rows(rows, kMaxBackwardBlockRows)) * kRows * size_t(cols > 0 ? cols : 0);
}

cudaError_t launch_bias_gelu_backward(const float* dy, const float* x, const float* b, int64_t rows, int cols,
                                      float* dx, float* db, float* workspace, cudaStream_t stream) {
  return backward(dy, x, b, rows, cols, dx, db, workspace, stream);
}

cudaError_t launch_bias_gelu_backward(const __nv_bfloat16* dy, const __nv_bfloat16* x, const float* b, int64_t rows,
                                      int cols, __nv_bfloat16* dx, float* db, float* workspace, cudaStream_t stream) {
  return backward(dy, x, b, rows, cols, dx, db, workspace, stream);
}

}  // namespace ablenerf
