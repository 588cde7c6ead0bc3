#pragma once
// Error-guided ray sampling (train.ray_sampling = "error"), in the spirit of instant-ngp's error
// map: the training pixels are cut into square tiles, each tile keeps the recent squared error of
// the rays drawn from it, and a step's rays come from tiles in proportion to that error, mixed
// with uniform sampling so that no pixel is ever left out. On object scenes most pixels are
// background that the model fits in the first minutes; the mix spends the rays where the image is
// still wrong. The loss is not re-weighted: the objective leans towards the pixels it gets wrong.
//
// Deterministic: the draws come from the caller's CPU generator and the errors arrive in batch
// order, so every process of a data-parallel group holding the same map draws the same batch.
#include <torch/torch.h>

#include <cstdint>
#include <vector>

namespace ablenerf {

struct ErrorMapOptions {
  int64_t tile = 4;             // tile side in pixels (smaller at the right and bottom image edges)
  double uniform_share = 0.25;  // probability mass spread over pixels uniformly
};

class ErrorMap {
 public:
  // `keep`, when defined, is (images, height, width) bool: only its true pixels are ever drawn (a
  // capture's masks, Split::mask). Tiles then count their kept pixels only: the uniform share is
  // spread over kept pixels, a tile with none is never drawn, and a ray lands on one of its tile's
  // kept pixels, uniformly. At least one pixel must be kept.
  ErrorMap(int64_t images, int64_t height, int64_t width, ErrorMapOptions options,
           const torch::Tensor& keep = torch::Tensor());

  // Flat pixel indices (image * H * W + row * W + col), int64 on the CPU, of `n` rays: a tile with
  // probability `probabilities()[tile]`, then a pixel uniformly inside it (three uniforms per ray).
  torch::Tensor draw(int64_t n, torch::Generator& gen);

  // Records the per-ray squared error (any float dtype, any device; (n,)) of the rays at `pixels`
  // (flat indices as `draw` returns them), in order: each tile's error moves halfway to the new
  // value; non-finite errors are skipped. The first call sets every tile to that batch's mean, so
  // tiles not yet seen keep a typical early error and are visited soon.
  void observe(const torch::Tensor& pixels, const torch::Tensor& squared_error);

  // P(tile) = (1 - share) * e_tile / sum(e) + share * pixels_tile / pixels (uniform until the first
  // observation or when every error is zero), pixels counting kept pixels only and e_tile 0 for a
  // tile without any. float64, (tiles,).
  torch::Tensor probabilities() const;
  int64_t tiles() const { return static_cast<int64_t>(error_.size()); }
  int64_t tile_of(int64_t pixel) const;

  // For checkpoints: [seeded, e_0, e_1, ...] as float64.
  torch::Tensor state() const;
  void set_state(const torch::Tensor& state);  // throws std::invalid_argument on a size mismatch

 private:
  // A tile's image, first pixel row and column, and size (smaller at the right and bottom edges).
  struct TileRect {
    int64_t image, row, col, height, width;
  };
  TileRect tile_rect(int64_t tile) const;
  void rebuild_cdf();

  int64_t images_, height_, width_;
  ErrorMapOptions opt_;
  int64_t tiles_x_, tiles_y_;
  std::vector<double> error_;
  std::vector<double> cdf_;  // inclusive running sum of the tiles' probabilities
  // With a mask: tile t's kept pixels are kept_[kept_start_[t] .. kept_start_[t + 1]), each as its
  // row * opt_.tile + col inside the tile. Empty without a mask.
  std::vector<int64_t> kept_start_;
  std::vector<uint16_t> kept_;
  // Each tile's drawable pixels (all of its pixels without a mask), counted once: the map's
  // probabilities are rebuilt every step, over every tile of every image.
  std::vector<int32_t> counts_;
  int64_t kept_count(int64_t tile) const;
  // f(tile, P(tile)) for every tile in order, P as probabilities() documents.
  template <class F>
  void each_probability(F&& f) const;
  bool seeded_ = false, dirty_ = true;
};

}  // namespace ablenerf
