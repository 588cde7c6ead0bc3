#pragma once
// Launches of the hash-grid encoding's CUDA kernels (hash_grid_cuda.cu) on raw device pointers and
// a stream. CUDA headers only. positions (n, 3), table and grad_table (levels, table_size,
// features), out and grad_out (n, levels, features): contiguous float32; features <= 8.
#include <cuda_runtime.h>

#include <cstdint>

#include "kernels/hash_grid_shape.h"

namespace ablenerf {

// out = the interpolated rows at each point (one thread per point and level).
cudaError_t launch_hash_grid_forward(const float* positions, int64_t n, const float* table, const HashGridShape& s,
                                     float* out, cudaStream_t stream);

// grad_table += the scatter of grad_out into the rows each point read (atomic adds; the caller
// zeroes grad_table first).
cudaError_t launch_hash_grid_backward(const float* positions, int64_t n, const float* grad_out, const HashGridShape& s,
                                      float* grad_table, cudaStream_t stream);

// grad_positions (n, 3) = the positions' gradient (one thread per point, no atomics; every row
// written).
cudaError_t launch_hash_grid_backward_positions(const float* positions, int64_t n, const float* grad_out,
                                                const float* table, const HashGridShape& s, float* grad_positions,
                                                cudaStream_t stream);

}  // namespace ablenerf
