#pragma once
// Training checkpoints: model, Adam state, step, the ray stream's RNG state and error map, and the
// resolved config, in one file written atomically (temp file + fsync + rename: a kill -9 at any
// moment leaves the previous or the new checkpoint, never a partial one) and protected by a
// checksum (a truncated or corrupted file is reported, never loaded).
//
// File layout: "ABLECKPT" | u32 format version | u64 payload bytes | u64 FNV-1a-64 of the payload |
// payload = a torch::serialize archive.
#include <torch/torch.h>

#include <cstdint>
#include <string>

#include "model/able_nerf.h"
#include "util/config.h"

namespace ablenerf {

struct TrainState {
  int64_t step = 0;            // optimiser steps done
  torch::Tensor rng_state;     // RaySampler::rng_state()
  torch::Tensor error_map;     // RaySampler::map_state() (undefined without an error map)
  double elapsed_seconds = 0;  // training wall time so far
};

uint64_t fnv1a64(const char* data, size_t size);

// Writes the checkpoint atomically. Throws EnvironmentError naming `path` when it cannot be written
// (disk full, permissions); an earlier checkpoint at `path` is then left intact.
void save_checkpoint(const std::string& path, const Config& config, AbleNerf& model, torch::optim::Adam& optim,
                     const TrainState& state);

// Loads into `model` and `optim` (already built from `config`). Refuses, with InputError naming the
// mismatch, a checkpoint whose model config or format version differs, and one whose checksum or
// length is wrong.
TrainState load_checkpoint(const std::string& path, const Config& config, AbleNerf& model, torch::optim::Adam& optim);

}  // namespace ablenerf
