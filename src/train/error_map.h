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
//
// A step costs O(rays x log(tiles)), not O(tiles): the error part is drawn through a Fenwick tree
// (a binary indexed tree of prefix sums) over the tiles' errors in fixed point, updated per observed
// ray, and the uniform part straight from the pixels. Integer sums make the tree a function of the
// errors alone, whatever order the updates came in, so a map restored from a checkpoint draws what
// the map that was saved would have drawn.
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
  // The draws' fixed point: a tile's error in units of 2^-32, clamped to kMaxTileError (a ray's
  // squared RGB error is at most 3 for colours in [0, 1]), so that the int64 total holds 10^8 tiles.
  static constexpr double kFixedScale = 4294967296.0;
  static constexpr double kMaxTileError = 16.0;

  // `keep`, when defined, is (images, height, width) bool: only its true pixels are ever drawn (a
  // capture's masks, Split::mask). Tiles then count their kept pixels only: the uniform share is
  // spread over kept pixels, a tile with none is never drawn, and a ray lands on one of its tile's
  // kept pixels, uniformly. At least one pixel must be kept.
  ErrorMap(int64_t images, int64_t height, int64_t width, ErrorMapOptions options,
           const torch::Tensor& keep = torch::Tensor());

  // Flat pixel indices (image * H * W + row * W + col), int64 on the CPU, of `n` rays: a tile with
  // probability `probabilities()[tile]`, then a pixel uniformly inside it (three uniforms per ray:
  // the first picks the uniform or the error part and, rescaled, the pixel or the tile).
  torch::Tensor draw(int64_t n, torch::Generator& gen);

  // Records the per-ray squared error (any float dtype, any device; (n,)) of the rays at `pixels`
  // (flat indices as `draw` returns them), in order: each tile's error moves halfway to the new
  // value; non-finite errors are skipped. The first call sets every tile to that batch's mean, so
  // tiles not yet seen keep a typical early error and are visited soon.
  void observe(const torch::Tensor& pixels, const torch::Tensor& squared_error);

  // P(tile) = (1 - share) * e_tile / sum(e) + share * pixels_tile / pixels (uniform until the first
  // observation or when every error is zero), pixels counting kept pixels only and e_tile 0 for a
  // tile without any; e_tile as the draws see it, in fixed point (multiples of 2^-32, at most
  // kMaxTileError). float64, (tiles,).
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
  // A tile's error as the tree holds it: fixed point, 0 for a tile without drawable pixels.
  int64_t fixed_error(size_t tile) const;
  void rebuild_tree();                       // O(tiles), from error_
  void add_to_tree(size_t tile, int64_t d);  // O(log tiles)
  size_t tree_find(int64_t target) const;    // the tile whose prefix range holds target

  int64_t images_, height_, width_;
  ErrorMapOptions opt_;
  int64_t tiles_x_, tiles_y_;
  std::vector<double> error_;
  // The Fenwick tree over fixed_error(t) (tree_[i] sums the tiles (i - lowbit(i), i], 1-based), the
  // fixed-point error each tile holds in it, and their total.
  std::vector<int64_t> tree_, fixed_;
  int64_t fixed_total_ = 0;
  // With a mask: tile t's kept pixels are kept_[kept_start_[t] .. kept_start_[t + 1]), each as its
  // row * opt_.tile + col inside the tile. Empty without a mask.
  std::vector<int64_t> kept_start_;
  std::vector<uint16_t> kept_;
  // Each tile's drawable pixels (all of its pixels without a mask), counted once.
  std::vector<int32_t> counts_;
  int64_t kept_count(int64_t tile) const;
  int64_t drawable_pixels() const;
  // The uniform part's share of the draws: the option's once an error is known, else all of them.
  double uniform_share_now() const;
  // The flat pixel index of kept_[at], a kept pixel of tile t.
  int64_t kept_pixel(int64_t t, int64_t at) const;
  bool seeded_ = false;
};

}  // namespace ablenerf
