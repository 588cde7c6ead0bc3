#pragma once
// The hash-grid encoding's CPU loops (hash_grid.h) on raw float32 pointers. No checks: the wrapper
// in hash_grid.cpp has made them.
#include <cstdint>

#include "kernels/cpu_features.h"
#include "kernels/hash_grid_shape.h"

namespace ablenerf {

// The loops go through at::parallel_for (points, or levels for the scatter). Our code is compiled
// without OpenMP, and there ATen's header runs them on the calling thread: the CPU's two cores come
// from the ray split instead, each slice's thread running its own lookups (kernels/cpu_parallel.h).
//
// `scales` (n, levels), where not null, multiplies each point's output at each level (the grid front
// end's anti-aliasing weights, model/grid_embedding.h) and so the gradients that flow back through
// it: the same products, in the same order, as a separate multiply of the output and of its gradient.
//
// out (n, levels, features) = the interpolated rows of table (levels, table_size, features) at
// positions (n, 3), times scales.
void hash_grid_forward_cpu(const float* positions, int64_t n, const float* table, const HashGridShape& s,
                           const float* scales, float* out);

// grad_table (levels, table_size, features) += the scatter of grad_out (n, levels, features) into
// the rows each point read, with its trilinear weights. Level by level, points in order (split by
// level where it runs in parallel): no two threads touch one row, and the sums come out the same on
// every run.
void hash_grid_backward_cpu(const float* positions, int64_t n, const float* grad_out, const HashGridShape& s,
                            const float* scales, float* grad_table);

// grad_positions (n, 3) = the gradient of sum(grad_out * out) with respect to the positions: at
// every level, each vertex row's dot product with grad_out times its weight's derivative
// (hash_grid_corners_with_gradient). Points split across threads; each writes only its own row.
void hash_grid_backward_positions_cpu(const float* positions, int64_t n, const float* grad_out, const float* table,
                                      const HashGridShape& s, const float* scales, float* grad_positions);

// How the AVX-512 form's gather reads a level's rows: one 64-bit vector gather per 8 points and
// vertex (Gathers), or one 8-byte load per point and vertex (Loads). Both form the same products and
// sums in the same order, so their outputs are the same bits. Gathers took 0.65x the time of loads
// on an Intel Sapphire Rapids core; loads 0.85x the time of gathers on an AMD Zen 4 core, whose
// gathers are microcoded (docs/benchmarks/history.md, "The grid's rows by vector gathers on Intel
// cores"). The best: Gathers on an Intel CPU, Loads on any other.
enum class HashGridReads { Loads, Gathers };
HashGridReads hash_grid_best_reads();

// The instruction forms of the table's gather and scatter: AVX-512 (16 points at a time: their cells,
// rows and trilinear weights computed as vectors, the rows read as HashGridReads says; for 2 floats
// per row, the presets' width, else as Scalar) and the scalar loops every x86-64 CPU runs. The forms
// agree up to the rounding of a fused multiply-add in the forward; the scatter adds the same
// products in the same order (each point's 8 vertices in turn), so its sums are the same bits.
void hash_grid_forward_cpu_in(CpuVectorForm form, const float* positions, int64_t n, const float* table,
                              const HashGridShape& s, const float* scales, float* out,
                              HashGridReads reads = hash_grid_best_reads());
void hash_grid_backward_cpu_in(CpuVectorForm form, const float* positions, int64_t n, const float* grad_out,
                               const HashGridShape& s, const float* scales, float* grad_table);

// The scatter of one level alone, on the calling thread: level_rows (table_size, features) += the
// scatter of grad_out's level `level` (the same products and order as hash_grid_backward_cpu_in's).
// For a caller that has the level's rows in its cache already (kernels/table_gradient.h).
void hash_grid_backward_level_cpu_in(CpuVectorForm form, const float* positions, int64_t n, const float* grad_out,
                                     const HashGridShape& s, int level, const float* scales, float* level_rows);

}  // namespace ablenerf
