#pragma once
// The multiresolution hash-grid encoding (hash_grid_shape.h): each point of the unit cube gets, at
// every level, the trilinear interpolation of a trainable table's rows at its cell's vertices. One
// operation in three forms that address the table alike: CPU loops (hash_grid_cpu.h), CUDA kernels
// (hash_grid_launch.h) and the plain LibTorch reference below, which the tests compare both with.
// The model's grid front end (model/grid_embedding.h) is its user.
#include <torch/torch.h>

#include "kernels/cpu_parallel.h"
#include "kernels/hash_grid_shape.h"

namespace ablenerf {

class TableGradient;

// `levels` levels of 2^log2_table rows of `features` floats, from base_resolution to max_resolution
// cells per side in a geometric progression (instant-ngp eq. 2-3: b = exp((ln max - ln base) /
// (levels - 1)), resolution_l = floor(base * b^l)). Throws std::invalid_argument on a shape the
// kernels do not take (levels 1..32, features 1..8, log2_table 1..24, 1 <= base <= max).
HashGridShape hash_grid_shape(int levels, int features, int log2_table, int base_resolution, int max_resolution);

// positions: (N, 3) float32, contiguous, coordinates in [0, 1] (clamped; NaN counts as 0);
// table: (levels, table_size, features) float32, contiguous, on the positions' device.
// Returns (N, levels, features) float32. Differentiable in the table and in the positions (the
// trilinear weights' derivatives, computed only when the positions require a gradient: camera
// refinement moves the samples; zero along an axis outside [0, 1]). CPU tensors run the project's loops (the table's
// gradient is added level by level, points in order: no lock, the same sums every run); CUDA tensors the
// kernels (atomic adds), or throw "built without CUDA kernels" where those were not built. Throws c10::Error naming the
// argument on bad input.
// With `gradient` (kernels/table_gradient.h), on the CPU, while the calling thread has a key open
// and the table requires a gradient: the table's scatter is deferred to it instead of autograd.
// With `scales` (N, levels) float32 on the positions' device: each point's output at each level
// times its scale, i.e. hash_grid_encode(...) * scales.unsqueeze(-1); on the CPU, for scales that
// take no gradient, inside the loops (one pass over the output less, forward and backward).
torch::Tensor hash_grid_encode(const torch::Tensor& positions, const torch::Tensor& table, const HashGridShape& shape,
                               TableGradient* gradient = nullptr, const torch::Tensor& scales = {});

// The entries (flat, as stored) of a (levels, table_size, features) table that lookups can reach:
// every row of a hashed level, the vertices' rows of a dense one (hash_grid_level_rows); levels that
// meet joined into one range.
IndexRanges hash_grid_table_entries(const HashGridShape& shape);

// The same in plain LibTorch ops (index_select and products; autograd gives the table's and the
// positions' gradients),
// on any device, float32 or float64 tables.
torch::Tensor hash_grid_encode_reference(const torch::Tensor& positions, const torch::Tensor& table,
                                         const HashGridShape& shape);

// hash_grid_row in LibTorch ops: the rows of `level` for the int64 vertex coordinates x, y, z.
torch::Tensor hash_grid_rows_reference(const torch::Tensor& x, const torch::Tensor& y, const torch::Tensor& z,
                                       const HashGridShape& shape, int level);

}  // namespace ablenerf
