#pragma once
// Training batches: rays drawn across every pixel of every training image (uniformly, or guided by
// an error map: train/error_map.h), generated on the fly from the poses (docs/MODEL.md, section 1: no table of all
// rays). Every process of a data-parallel group draws the same global batch from one identically
// seeded stream and keeps its own slice, so a run does not depend on how many processes share it.
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
  RaySampler(const Split& split, const Intrinsics& k, const torch::Device& device, uint64_t seed,
             std::optional<ErrorMapOptions> error_map = std::nullopt);

  // The next global batch of `global_size` rays; returns this rank's slice
  // [rank*global/world, (rank+1)*global/world).
  RayBatch next(int64_t global_size, int rank = 0, int world = 1);

  // The pixel indices of the next global batch (advances the stream); exposed for tests.
  torch::Tensor draw(int64_t global_size);
  RayBatch gather(const torch::Tensor& flat_indices) const;

  // The per-ray squared errors of a drawn global batch, in the order drawn (all of it, every rank
  // the same), for the error map; nothing without one.
  void observe(const torch::Tensor& flat_indices, const torch::Tensor& squared_error);
  bool error_guided() const { return map_.has_value(); }

  // The random stream's state and the error map's (undefined without one), for checkpoints.
  torch::Tensor rng_state() const;
  void set_rng_state(const torch::Tensor& state);
  torch::Tensor map_state() const;
  void set_map_state(const torch::Tensor& state);

 private:
  torch::Tensor images_, c2w_;  // on device: (N*H*W,3), (N,3,4)
  Intrinsics k_;                // the first image's camera (the image size of every image)
  CameraTable cams_;            // on device: one row per image
  int64_t pixels_;
  torch::Generator gen_;  // CPU stream: identical on every device and rank
  std::optional<ErrorMap> map_;
  // Uniform draws over a mask's kept pixels: an ErrorMap that never observes (uniform share 1).
  std::optional<ErrorMap> kept_;
};

}  // namespace ablenerf
