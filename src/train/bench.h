#pragma once
// `ablenerf bench`: model throughput on one device. Measures a full training step (forward,
// backward, Adam) and an inference forward at a fixed ray batch, the device's own sgemm peak in
// the same run, and reports rays/s, achieved FLOP/s (from an analytic count of the matrix
// products), the fraction of the measured peak and peak memory as one JSON object.
#include <torch/torch.h>

#include <nlohmann/json.hpp>
#include <vector>

#include "util/config.h"

namespace ablenerf {

// Floating-point operations per ray of the matrix products the model runs (dense GEMMs,
// attention scores and attention-weighted sums; 2 FLOP per multiply-add). Element-wise work
// (IPE, softmax, LayerNorm, GELU, resampling) is not counted. The LE query projection, computed
// once per forward call for the whole batch, is not a per-ray cost and is left out.
struct FlopCount {
  double forward = 0;   // inference forward
  double backward = 0;  // gradients of a training step (no-grad products excluded)
  double train() const { return forward + backward; }
};
FlopCount model_flops_per_ray(const ModelConfig& cfg);

struct BenchOptions {
  torch::Device device{torch::kCPU};
  int64_t train_rays = 64;     // rays per training step
  int64_t micro_batch = 0;     // rays per forward/backward within a step (0 = the whole step)
  int64_t render_rays = 0;     // rays per inference forward (0 = same as train_rays)
  int64_t steps = 5;           // timed repetitions; the median is reported
  int64_t warmup = 1;          // untimed repetitions first
  int64_t image_side = 800;    // the "seconds per image" extrapolation is for side x side pixels
  int64_t matmul_size = 2048;  // n of the n x n x n sgemm that measures the device peak
  int64_t matmul_reps = 5;
  double near = 2.0, far = 6.0;
  uint64_t seed = 4;
  // After the timed steps, this many more training steps under LibTorch's autograd profiler
  // (BenchMeasurements::trace_json); 0 = none. They are not part of any reported timing.
  int64_t trace_steps = 0;
};

// One timed quantity: per-repetition wall and process-CPU seconds.
struct Timing {
  std::vector<double> wall_s, cpu_s;
  double wall_median() const;
  double cpu_median() const;
};

struct BenchMeasurements {
  Timing train, render, matmul;
  int64_t peak_memory_bytes = -1;  // -1 = unknown
  std::string peak_memory_source;
  int64_t threads = 1;  // intra-op threads used
  int64_t parameters = 0;
  std::string matmul_dtype;  // dtype of the peak-measuring product ("fp32" | "bf16")
  bool device_step = false;  // the trainer ran its device form (CUDA, one process)
  bool graph = false;        // ... captured as a CUDA graph
  // The operator trace of BenchOptions::trace_steps training steps (Chrome trace JSON, one "X"
  // event per LibTorch op with its start and duration in microseconds), or empty. The legacy
  // profiler records the calling thread only: with the CPU ray split (compute.cpu_split = "rays")
  // it holds the first slice's forward and backward and the whole rest of the step. On CUDA with
  // LibTorch >= 2 it is Kineto's trace instead: host ops plus the GPU's kernels (CUPTI).
  std::string trace_json;
};

// What a trace spends per step: every op's self time (its duration less that of the ops nested
// in it on the same thread) summed by name, divided by `steps`. Returns {"steps", "ops_per_step",
// "self_ms_per_step", "top": [{"op", "self_ms_per_step", "calls_per_step"}, ...]} with the `top`
// ops of largest self time first. A CUDA trace (Kineto's: events of category "kernel",
// "gpu_memcpy" or "gpu_memset") adds "gpu": {"events_per_step", "busy_ms_per_step" (their summed
// durations), "top": [{"kernel", "ms_per_step", "share", "calls_per_step"}, ...]}; those events
// are left out of the host's self times. Throws std::invalid_argument when the trace is not such JSON.
nlohmann::json trace_summary(const std::string& trace_json, int64_t steps, size_t top);

// Median of a non-empty list (mean of the middle two for an even count).
double median(std::vector<double> values);

// Runs every measurement (warm-up, then `steps` timed repetitions each).
BenchMeasurements measure(const Config& cfg, const BenchOptions& opts);

// The JSON report from measurements (pure arithmetic, no timing).
nlohmann::json bench_report(const Config& cfg, const BenchOptions& opts, const BenchMeasurements& m);

}  // namespace ablenerf
