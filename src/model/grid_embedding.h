#pragma once
// The grid front end (model.embedding = "grid"; docs/MODEL.md, "Grid front end"): in place of stage
// 2's integrated positional encoding, each frustum Gaussian reads a trainable multiresolution hash
// grid (instant-ngp; kernels/hash_grid.h) at its mean, each level's features scaled down by the
// Gaussian's size against the level's cell (Zip-NeRF's anti-aliasing, Barron et al. 2023, section
// 2: erf(1 / sqrt(8 sigma^2 n^2))), so that a wide frustum reads only the levels it spans, as IPE
// fades the frequencies it spans. The features then go through stage 3's volume-embedding MLP to
// become the sample tokens the AB transformer attends over; the rest of the model is the paper's.
//
// The grid spans a cube of the space the samples live in: [-grid_bound, grid_bound]^3 of the world
// for bounded scenes, the contracted ball's [-2, 2]^3 for unbounded ones (model/contraction.h), and
// NDC's [-1, 1]^3 for forward-facing ones (model/ndc.h). Samples outside the cube read zeros.
//
// The table's learning rate is model.grid_lr_scale times the run's: the parameter Adam sees is the
// table divided by that scale (the lookup multiplies it back), so every optimiser form, checkpoint
// and schedule of the project applies unchanged.
#include <torch/torch.h>

#include <memory>

#include "kernels/hash_grid_shape.h"
#include "kernels/cpu_parallel.h"
#include "kernels/table_gradient.h"
#include "data/data_config.h"
#include "model/model_config.h"

namespace ablenerf {

// The cube the grid spans: [lo, hi]^3 of the sample space.
struct GridCube {
  double lo = -1, hi = 1;
};
GridCube grid_cube(const ModelConfig& cfg, SceneKind scene);

// Zip-NeRF's per-level down-weighting: erf(1 / sqrt(8 sigma2 n^2)) for a Gaussian of variance
// sigma2 (in units of the cube's side, (...)) against levels of n cells per side (L): (..., L).
torch::Tensor grid_level_weights(const torch::Tensor& sigma2, const torch::Tensor& resolution);

class GridEmbeddingImpl : public torch::nn::Module {
 public:
  // The front end's grid (model.grid_*).
  GridEmbeddingImpl(const ModelConfig& cfg, GridCube cube);
  // Any grid of that shape, e.g. the proposal field's (model/proposal.h).
  GridEmbeddingImpl(const HashGridShape& shape, GridCube cube, double lr_scale);
  // Gaussians (mean, cov: (..., 3), cov the diagonal) -> features (..., levels * features); where
  // `inside` is given, also whether each mean lies in the grid's cube (faces included): (...) float32 1/0.
  torch::Tensor forward(const torch::Tensor& mean, const torch::Tensor& cov, torch::Tensor* inside = nullptr);
  int64_t width() const { return int64_t{shape_.levels} * shape_.features; }
  const HashGridShape& shape() const { return shape_; }
  // The table as the lookup reads it: (levels, table_size, features).
  torch::Tensor table() const { return table_ * lr_scale_; }
  // The parameter itself (table() / lr_scale()) and the scale.
  const torch::Tensor& table_parameter() const { return table_; }
  double lr_scale() const { return lr_scale_; }
  // Where a CPU training step's threads gather the table's gradient (kernels/table_gradient.h):
  // lookups on a thread with a key open defer their scatters there, and the step's finish puts
  // their sum in .grad.
  TableGradient& table_gradient() const { return *table_gradient_; }
  // The table parameter's entries that lookups can reach (hash_grid_table_entries,
  // kernels/hash_grid.h). The table gradient writes only these (kernels/table_gradient.h), and the
  // trainer tells Adam.
  IndexRanges table_entries_read() const;
  // Under compute.attention = "fused" (set by AbleNerf::set_compute) the points' unit coordinates
  // and level weights come from one CPU loop (kernels/sample_encoding_cpu.h) where nothing
  // differentiates through them; "plain" keeps the tensor ops below.
  void set_fused_inputs(bool fused) { fused_inputs_ = fused; }

 private:
  HashGridShape shape_;
  GridCube cube_;
  double lr_scale_;
  bool fused_inputs_ = true;
  // The points (N,3) in the cube's unit coordinates, and whether each lies in [0, 1]^3 -> (N) bool.
  torch::Tensor unit_coordinates(const torch::Tensor& mean) const;
  static torch::Tensor in_unit_cube(const torch::Tensor& unit);

  torch::Tensor table_;       // the parameter: the table / lr_scale
  torch::Tensor resolution_;  // (levels) cells per side, a buffer for the weights
  std::shared_ptr<TableGradient> table_gradient_;
};
TORCH_MODULE(GridEmbedding);

}  // namespace ablenerf
