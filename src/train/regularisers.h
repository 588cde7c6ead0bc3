#pragma once
// Loss terms beside the colour loss, for the grid front end (docs/MODEL.md, "Grid front end"); both
// are off in the paper's presets.
#include <torch/torch.h>

namespace ablenerf {

// mip-NeRF 360's distortion loss (Barron et al. 2022, section 4) per ray, in its discrete form:
//   sum_ij w_i w_j |m_i - m_j| + 1/3 sum_i w_i^2 (s_i+1 - s_i),   m_i = (s_i + s_i+1) / 2,
// for weights w (B,S) over intervals with sorted fence-posts s (B,S+1) -> (B,). The double sum is
// evaluated in O(S) with prefix sums: sum_ij = 2 sum_i w_i (m_i W_<i - (wm)_<i).
torch::Tensor distortion_loss(const torch::Tensor& weights, const torch::Tensor& s);

// The share of train.distortion_weight a step carries at `fraction` of the schedule when the term
// begins at `start` (train.distortion_start): 0 before it, rising linearly to 1 over the next
// `ramp` of the schedule (train.distortion_ramp), 1 after; 1 throughout when start is 0.
inline constexpr double kDistortionRamp = 0.1;
double distortion_ramp(double start, double fraction, double ramp = kDistortionRamp);

// The ray token's attention over the samples as a distribution: weights (B,S) / their sum. The
// attention the ray token pays itself (column 0, dropped from the weights) is no place along the
// ray; a distortion loss on the raw weights is lowered by moving attention there, which says
// nothing of where the surface is, so the loss is put on this distribution instead.
torch::Tensor attention_distribution(const torch::Tensor& weights);

// mip-NeRF 360's proposal loss (Barron et al. 2022, section 3, eq. 13-14) per ray: the proposal's
// histogram (fence-posts s_p (B,N+1), weights w_p (B,N)) must bound the target's (s_t (B,M+1), w_t
// (B,M)) from above: with bound_i the proposal's weight over every interval that overlaps target
// interval i,  sum_i max(0, w_t_i - bound_i)^2 / (w_t_i + eps)  -> (B,). The target is treated as a
// constant (detach it): only the proposal learns from this. Both fence-post sets sorted, in one
// coordinate. As in mip-NeRF 360's code, a proposal interval that only touches a target interval at a
// shared post counts as overlapping it.
torch::Tensor proposal_loss(const torch::Tensor& s_p, const torch::Tensor& w_p, const torch::Tensor& s_t,
                            const torch::Tensor& w_t);

// Zip-NeRF's normalised weight decay (Barron et al. 2023): the sum over levels of the mean of the
// squared table entries of that level. table: (levels, rows, features) -> 0-d.
torch::Tensor grid_weight_decay(const torch::Tensor& table);

// The same term on the table the lookup reads, scale * param (model/grid_embedding.h: the parameter
// is the table over its learning-rate scale), times `weight`, with its gradient added straight into
// param's .grad: weight * scale^2 / (rows * features) * sum(param^2), gradient twice that coefficient
// times param. Two passes over the table and no temporaries of its size, where autograd through
// grid_weight_decay makes five (the scaled table, its square, and their backward): the table is the
// model's largest tensor (2^19 rows in the capture preset) and those passes were a fifth of a CPU
// step. Returns the term's value (0-d, param's dtype); no graph is recorded.
torch::Tensor add_grid_weight_decay(const torch::Tensor& param, double scale, double weight);

// That coefficient, weight * scale^2 / (rows * features): the term is it times sum(param^2). A CPU
// training step applies it in the pass that gathers the table's gradient (kernels/table_gradient.h).
double grid_decay_coefficient(const torch::Tensor& param, double scale, double weight);

// weight x the mean over param's first dimension of its rows' squared norms (the per-photo colour
// maps and camera corrections, each row one photo's), its gradient added straight into param's .grad
// as add_grid_weight_decay does. Returns the value (0-d, param's dtype).
torch::Tensor add_row_decay(const torch::Tensor& param, double weight);

}  // namespace ablenerf
