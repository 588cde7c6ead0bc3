#include "model/grid_embedding.h"

#include <cmath>

#include "kernels/hash_grid.h"
#include "kernels/sample_encoding_cpu.h"
#include "data/data_config.h"
#include "model/model_config.h"

namespace ablenerf {

namespace {
// instant-ngp's initialisation of the table: uniform in [-1e-4, 1e-4].
constexpr double kTableInit = 1e-4;
// The contracted space's radius (model/contraction.h) and NDC's extent (model/ndc.h).
constexpr double kContractedRadius = 2.0;
constexpr double kNdcExtent = 1.0;
}  // namespace

GridCube grid_cube(const ModelConfig& cfg, SceneKind scene) {
  switch (scene) {
    case SceneKind::Unbounded: return {-kContractedRadius, kContractedRadius};
    case SceneKind::ForwardFacing: return {-kNdcExtent, kNdcExtent};
    case SceneKind::Auto:
    case SceneKind::Bounded: break;
  }
  return {-cfg.grid_bound, cfg.grid_bound};
}

torch::Tensor grid_level_weights(const torch::Tensor& sigma2, const torch::Tensor& resolution) {
  const auto n2 = (resolution * resolution).to(sigma2.dtype());
  // 1 / sqrt(8 sigma2 n^2); sigma2 = 0 gives +inf and erf(inf) = 1 (a point reads every level).
  return torch::erf(torch::rsqrt(8 * sigma2.unsqueeze(-1) * n2));
}

GridEmbeddingImpl::GridEmbeddingImpl(const ModelConfig& cfg, GridCube cube)
    : GridEmbeddingImpl(hash_grid_shape(cfg.grid_levels, cfg.grid_features, cfg.grid_log2_table,
                                        cfg.grid_base_resolution, cfg.grid_max_resolution),
                        cube, cfg.grid_lr_scale) {}

GridEmbeddingImpl::GridEmbeddingImpl(const HashGridShape& shape, GridCube cube, double lr_scale)
    : shape_(shape), cube_(cube), lr_scale_(lr_scale) {
  table_ = register_parameter(
      "table", (torch::rand({shape_.levels, shape_.table_size, shape_.features}) * 2 - 1) * (kTableInit / lr_scale_));
  std::vector<float> res(shape_.resolution, shape_.resolution + shape_.levels);
  resolution_ = register_buffer("resolution", torch::tensor(res));
  table_gradient_ = std::make_shared<TableGradient>(shape_);
}

IndexRanges GridEmbeddingImpl::table_entries_read() const { return hash_grid_table_entries(shape_); }

torch::Tensor GridEmbeddingImpl::unit_coordinates(const torch::Tensor& mean) const {
  return ((mean.to(torch::kFloat).reshape({-1, 3}) - cube_.lo) / (cube_.hi - cube_.lo)).contiguous();
}

torch::Tensor GridEmbeddingImpl::in_unit_cube(const torch::Tensor& unit) { return ((unit >= 0) & (unit <= 1)).all(-1); }

torch::Tensor GridEmbeddingImpl::forward(const torch::Tensor& mean, const torch::Tensor& cov,
                                         torch::Tensor* inside_out) {
  const double side = cube_.hi - cube_.lo;
  auto lead = mean.sizes().vec();
  lead.pop_back();
  // The lookup is linear in the table: scaling its output by lr_scale reads table(), without
  // materialising the scaled table.
  torch::Tensor unit, weights;  // (N,3), (N,L)
  if (fused_inputs_ && sample_encoding_cpu_available({mean, cov, resolution_})) {
    GridInputs in = grid_inputs_cpu(mean, cov, cube_.lo, cube_.hi, resolution_, lr_scale_);
    unit = std::move(in.unit);
    weights = std::move(in.weights);
    if (inside_out) *inside_out = in.inside.reshape(lead);
  } else {
    unit = unit_coordinates(mean);
    const auto inside = in_unit_cube(unit).unsqueeze(-1);  // (N,1)
    if (inside_out) *inside_out = inside.to(torch::kFloat).reshape(lead);
    // The Gaussian's size: the mean of its per-axis variances, in units of the cube's side.
    const auto sigma2 = cov.to(torch::kFloat).reshape({-1, 3}).mean(-1) / (side * side);
    weights = grid_level_weights(sigma2, resolution_) * inside * lr_scale_;
  }
  const auto features = hash_grid_encode(unit, table_, shape_, table_gradient_.get(), weights);  // (N,L,F)
  lead.push_back(width());
  return features.reshape(lead);
}

}  // namespace ablenerf
