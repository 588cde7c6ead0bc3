#pragma once
// What the training step needs from CUDA beyond tensors, kept out of the trainer so that it
// compiles without CUDA: a side stream for the whole training run, the capture of the step's
// device work as one CUDA graph (replayed every step after a few eager warm-up steps), and
// asynchronous staging of the step's inputs (ray indices) and outputs (loss figures) through
// pinned host buffers, so that no step waits for the GPU.
//
// Without a CUDA LibTorch >= 2 the constructor throws (CudaStep::available() says so first).
#include <torch/torch.h>

#include <functional>
#include <memory>
#include <optional>
#include <vector>

namespace ablenerf {

class CudaStep {
 public:
  static bool available(const torch::Device& device);

  // graph = false: every step runs eagerly (same work, same order, same numbers).
  CudaStep(const torch::Device& device, bool graph, int64_t warmup_steps);
  ~CudaStep();
  CudaStep(const CudaStep&) = delete;
  CudaStep& operator=(const CudaStep&) = delete;

  // Copies `host` (a CPU tensor) into `device_tensor` (same shape and dtype) asynchronously
  // through a pinned buffer; the host tensor may be reused at once.
  void upload(const torch::Tensor& host, torch::Tensor& device_tensor);
  // Runs `body` for one step: eagerly (after `before_eager`) while warming up or without a graph;
  // then captures it once (after `before_eager`) and replays it from there on.
  void run(const std::function<void()>& body, const std::function<void()>& before_eager);
  bool captured() const;
  // Queues a copy of `values` (a small device tensor) to the host; take() returns the values
  // queued by the previous call to queue() (waiting for them if needed), or nothing the first time.
  void queue(const torch::Tensor& values);
  std::optional<std::vector<double>> take();
  // Waits for every queued step and returns the values of the last queue() (nothing if none).
  std::optional<std::vector<double>> drain();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace ablenerf
