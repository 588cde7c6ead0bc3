#pragma once
// Training batches: rays drawn across every pixel of every training image (uniformly, or guided by
// an error map: train/error_map.h), generated on the fly from the poses (docs/MODEL.md, section 1: no table of all
// rays; the lens's part of each pixel's ray, which depends on its camera alone, is computed once per
// camera). Every process of a data-parallel group draws the same global batch from one identically
// seeded stream and keeps its own slice, so a run does not depend on how many processes share it.
//
// Coarse pixels (train.coarse_pixel_*; docs/MODEL.md, "Coarse pixels first"): with a factor f, the
// sampler also holds the training images reduced f times, each coarse pixel the mean of an f x f
// block (blocks that do not fit at the right and bottom edges are left out; with a mask, only
// blocks whose every pixel is kept). A coarse pixel's ray is the cone through the block's centre,
// f times wider: the ray of the camera whose focal length and principal point are divided by f,
// which is how mip-NeRF trains one scene at several scales. Flat indices past the full images'
// pixels (pixels() + image * h * w + row * w + col, h = H / f, w = W / f) name coarse pixels.
#include <torch/torch.h>

#include <optional>

#include "data/dataset.h"
#include "data/rays.h"
#include "train/error_map.h"

namespace ablenerf {

struct RayBatch {
  Rays rays;
  torch::Tensor target;  // (B,3)
  torch::Tensor photo;   // (B,) int64: the training photo each ray comes from (undefined when unknown)
  int64_t size() const { return target.size(0); }
  RayBatch slice(int64_t begin, int64_t end) const {
    return {rays.slice(begin, end), target.slice(0, begin, end),
            photo.defined() ? photo.slice(0, begin, end) : torch::Tensor()};
  }
};

class RaySampler {
 public:
  // images (N,H,W,3) and c2w (N,3,4) are moved to `device` once. Each image's camera is
  // split.cameras[i] when the split lists them, else `k`.
  // With `error_map`, pixels are drawn through an ErrorMap fed by observe(); without, uniformly.
  // Pixels outside split.mask (when it is defined) are never drawn.
  // coarse_factor > 1: also hold the images reduced that many times, for draws of coarse pixels.
  RaySampler(const Split& split, const Intrinsics& k, const torch::Device& device, uint64_t seed,
             std::optional<ErrorMapOptions> error_map = std::nullopt, int64_t coarse_factor = 0);

  // The next global batch of `global_size` rays; returns this rank's slice
  // [rank*global/world, (rank+1)*global/world).
  RayBatch next(int64_t global_size, int rank = 0, int world = 1);

  // The pixel indices of the next global batch (advances the stream); exposed for tests. The first
  // `coarse` of them are coarse pixels drawn uniformly (none without a coarse factor), the rest as
  // before; with coarse = 0 the stream is the one a sampler without coarse pixels draws.
  torch::Tensor draw(int64_t global_size, int64_t coarse = 0);
  // Any mix of full and coarse pixels; no host synchronisation (a captured CUDA graph runs it).
  RayBatch gather(const torch::Tensor& flat_indices) const;

  // The per-ray squared errors of a drawn global batch, in the order drawn (all of it, every rank
  // the same), for the error map; nothing without one. A coarse pixel's error is the error of the
  // tile holding its block's first pixel.
  void observe(const torch::Tensor& flat_indices, const torch::Tensor& squared_error);

  int64_t pixels() const { return pixels_; }
  // Coarse pixels that can be drawn (0 without a coarse factor, or when no block fits or is kept).
  int64_t coarse_pixels() const { return coarse_ ? coarse_pixels_ : 0; }
  bool error_guided() const { return map_.has_value(); }

  // The random stream's state and the error map's (undefined without one), for checkpoints.
  torch::Tensor rng_state() const;
  void set_rng_state(const torch::Tensor& state);
  torch::Tensor map_state() const;
  void set_map_state(const torch::Tensor& state);

 private:
  // A coarse pixel's index (counted from pixels_) as the reduced image it lies in, its row and column.
  struct CoarsePixel {
    torch::Tensor image, row, col;
  };
  CoarsePixel split_coarse(const torch::Tensor& coarse_idx) const;

  void build_lens_table(const std::vector<Intrinsics>& cameras, const torch::Device& device);
  // The rays of pixels of the images `image` whose rows of lens_ are `lens_rows`.
  Rays rays_from(const torch::Tensor& image, const torch::Tensor& lens_rows) const;
  // The rows of lens_ for a pixel, full (flat index below pixels_) or coarse (counted from pixels_).
  torch::Tensor full_lens_rows(const torch::Tensor& image, const torch::Tensor& pixel) const;
  torch::Tensor coarse_lens_rows(const CoarsePixel& c) const;

  torch::Tensor images_, c2w_;  // on device: (N*H*W,3), (N,3,4)
  Intrinsics k_;                // the first image's camera (the image size of every image)
  int64_t pixels_;
  // The lens's part of every ray that can be drawn, computed once per distinct camera
  // (lens_coordinates; the lens inverse is 20 Newton iterations of float64 tensor ops, a tenth of a
  // CPU step if run per batch): on device, (rows, 3) float32 x, y, radius, each camera's H*W full
  // pixels then its h*w coarse ones; per image, the first row of its camera's block.
  torch::Tensor lens_, lens_start_;
  torch::Generator gen_;  // CPU stream: identical on every device and rank
  std::optional<ErrorMap> map_;
  // Uniform draws over a mask's kept pixels: an ErrorMap that never observes (uniform share 1).
  std::optional<ErrorMap> kept_;
  // Coarse pixels: the reduced images (images * h * w, 3) on device, their size, and uniform draws
  // over the blocks that may be drawn (an ErrorMap that never observes).
  int64_t coarse_factor_ = 0, coarse_h_ = 0, coarse_w_ = 0, coarse_pixels_ = 0;
  torch::Tensor coarse_images_;
  std::optional<ErrorMap> coarse_;
};

// How many of a step's `rays` are coarse pixels at `fraction` of the schedule: share x rays at the
// start, falling linearly to none at `until` (train.coarse_pixel_share / _until), rounded.
int64_t coarse_pixel_rays(int64_t rays, double share, double until, double fraction);

}  // namespace ablenerf
