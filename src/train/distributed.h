#pragma once
// Data-parallel training over PyTorch's c10d: torchrun's environment conventions
// (RANK, WORLD_SIZE, LOCAL_RANK, MASTER_ADDR, MASTER_PORT), a TCPStore rendezvous, Gloo on CPU
// (NCCL on CUDA when the LibTorch has it). Gradients are summed with one all-reduce per bucket of
// parameters (the loss is already normalised by the global batch, so the sum is the global mean).
#include <torch/torch.h>

#include <memory>
#include <string>

#include "model/able_nerf.h"

namespace ablenerf {

struct DistEnv {
  int rank = 0, world_size = 1, local_rank = 0;
  std::string master_addr = "127.0.0.1";
  int master_port = 29500;
  bool launched = false;  // WORLD_SIZE is set (torchrun sets it even for one process)
  // Reads torchrun's variables; InputError naming the variable when one is malformed.
  static DistEnv from_environment();
};

class Distributed {
 public:
  virtual ~Distributed() = default;
  virtual int rank() const = 0;
  virtual int world_size() const = 0;
  // Copies rank 0's parameters to every rank.
  virtual void broadcast_parameters(AbleNerf& model) = 0;
  // Sums every gradient over the ranks (bucketed) together with `n` extra statistics.
  virtual void all_reduce_gradients(AbleNerf& model, double* stats, int n) = 0;
  virtual void barrier() = 0;

  // Joins the group described by `env` with `backend` ("gloo" or "nccl"); every collective fails
  // with a clear error after `timeout_s` seconds instead of hanging (a dead rank, say).
  static std::unique_ptr<Distributed> join(const DistEnv& env, const std::string& backend, double timeout_s);
  // Bytes of gradients per all-reduce call.
  static constexpr int64_t kBucketBytes = 16 << 20;
};

}  // namespace ablenerf
