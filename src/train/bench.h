#pragma once
// `ablenerf bench`: model throughput on one device. Measures a full training step (forward,
// backward, Adam) and an inference forward at a fixed ray batch, the device's own sgemm peak in
// the same run, and reports rays/s, achieved FLOP/s (from an analytic count of the matrix
// products), the fraction of the measured peak and peak memory as one JSON object; on the CPU also
// the transformer's token products timed alone (time_token_products), against one thread's share of
// that peak: how far the products are from the machine's limit, apart from the rest of the step.
#include <torch/torch.h>

#include <nlohmann/json.hpp>
#include <vector>

#include "model/flop_count.h"
#include "train/trace_summary.h"
#include "util/config.h"

namespace ablenerf {

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

// One token product of the model's transformer timed alone (CPU: kernels/small_gemm.h on one
// thread, the form a training slice runs): C (m x n) = op(A) (m x k) B (k x n).
struct ProductTiming {
  std::string name;
  int64_t m = 0, n = 0, k = 0;
  bool trans_a = false;  // a weight's gradient: the reduction runs over the tokens
  double seconds = 0;    // median of one call
  // The same product with bfloat16 operands (kernels/bf16_gemm.h, B packed in every call, as the
  // model does), where the CPU has AMX tiles; 0 otherwise.
  double bf16_seconds = 0;
};

// The transformer's token products at the shapes one ray slice of a training step runs (m = the
// slice's tokens, rays / workers x (samples + 1)): the projections and feed-forward layers forward
// and their weight gradients, each timed alone on the calling thread (kernels/small_gemm.h), and
// with bfloat16 operands where the CPU has the instructions.
std::vector<ProductTiming> time_token_products(int64_t width, int64_t ff_ratio, int64_t tokens);

// One of the transformer's fused CPU kernels timed alone on the calling thread at one training
// slice's shapes: its forward without autograd, and its forward and backward under autograd (the
// backward of a random output gradient).
struct KernelTiming {
  std::string name;
  int64_t rays = 0, tokens = 0;
  double forward_seconds = 0, train_seconds = 0;  // medians of one call
};

// The AB transformer layer's attention core under the ray mask (kernels/packed_attention.h) and
// its block tail (kernels/block_tail.h) for `rays` rays of samples + 1 tokens of the model's width,
// heads and feed-forward ratio, each alone on one thread.
std::vector<KernelTiming> time_token_kernels(int64_t width, int64_t heads, int64_t ff_ratio, int64_t samples,
                                             int64_t rays);

struct BenchMeasurements {
  Timing train, render, matmul;
  // CPU only: time_token_products and time_token_kernels at the run's shapes (empty on CUDA).
  std::vector<ProductTiming> products;
  std::vector<KernelTiming> kernels;
  int64_t peak_memory_bytes = -1;  // -1 = unknown
  std::string peak_memory_source;
  int64_t threads = 1;  // intra-op threads used
  int64_t parameters = 0;
  std::string matmul_dtype;  // dtype of the peak-measuring product ("fp32" | "bf16")
  std::string precision;     // the products' precision the model ran in ("auto" resolved)
  bool device_step = false;  // the trainer ran its device form (CUDA, one process)
  bool graph = false;        // ... captured as a CUDA graph
  // The operator trace of BenchOptions::trace_steps training steps (Chrome trace JSON, one "X"
  // event per LibTorch op with its start and duration in microseconds), or empty. The legacy
  // profiler records the calling thread only: with the CPU ray split (compute.cpu_split = "rays")
  // it holds the first slice's forward and backward and the whole rest of the step. On CUDA with
  // LibTorch >= 2 it is Kineto's trace instead: host ops plus the GPU's kernels (CUPTI).
  std::string trace_json;
  // The same for BenchOptions::trace_steps rendering forwards (the calling thread's ops: with the
  // ray split, the first slice's forward), or empty.
  std::string render_trace_json;
};

// Median of a non-empty list (mean of the middle two for an even count).
double median(std::vector<double> values);

// Runs every measurement (warm-up, then `steps` timed repetitions each).
BenchMeasurements measure(const Config& cfg, const BenchOptions& opts);

// The training speed of `cfg` on `device` in rays per second: the median of a few timed steps of
// its own trainer (train.rays_per_step rays each) on an in-memory split, after untimed ones.
double training_rays_per_s(const Config& cfg, const torch::Device& device);

// The JSON report from measurements (pure arithmetic, no timing).
nlohmann::json bench_report(const Config& cfg, const BenchOptions& opts, const BenchMeasurements& m);

}  // namespace ablenerf
