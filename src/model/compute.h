#pragma once
// How the model's arithmetic runs, without changing what it computes (issue 5's fast paths):
//  - the attention kernel: "fused" = on the CPU the direct-BLAS kernel over the packed projections
//    (model/attention_core.h), elsewhere scaled_dot_product_attention (LibTorch >= 2: flash /
//    memory-efficient kernels on CUDA); "plain" = explicit softmax(Q K^T / sqrt(d) + mask) V;
//  - the precision of the matrix products: "fp32", or "bf16" = CUDA autocast to bfloat16 with
//    the weights, the loss and the optimiser kept in fp32.
//  - how CPU threads share the work: "rays" = a slice of the rays per thread through the whole
//    model (model/cpu_parallel.h), "ops" = threads only inside each op or product.
// All are run-time switches so a benchmark can time every fast path against its reference in
// one process.
#include <torch/torch.h>

#include <string>

#include "util/config.h"

namespace ablenerf {

enum class AttentionKernel { Fused, Plain };
enum class Precision { Fp32, Bf16 };
enum class CpuSplit { Rays, Ops };

// Parse the config strings ("fused" | "plain", "fp32" | "bf16"); std::invalid_argument otherwise.
AttentionKernel parse_attention_kernel(const std::string& name);
Precision parse_precision(const std::string& name);
CpuSplit parse_cpu_split(const std::string& name);  // "rays" | "ops"
const char* to_string(AttentionKernel k);
const char* to_string(Precision p);

// True when this LibTorch has a fused attention kernel (LibTorch >= 2).
bool fused_attention_compiled();

// The attention kernel every attention layer of the process uses (default: Fused, which falls
// back to Plain where no fused kernel is compiled). A process-wide switch, like LibTorch's own
// backend flags, so that a benchmark can compare kernels on one model.
void set_attention_kernel(AttentionKernel kernel);
AttentionKernel attention_kernel();
// How CPU threads share the model's work (default: Rays). Process-wide, like the kernel switch.
void set_cpu_split(CpuSplit split);
CpuSplit cpu_split();
// True when bf16 autocast can run on `device` (a CUDA device, LibTorch >= 2).
bool bf16_autocast_available(const torch::Device& device);

// bf16 autocast on CUDA for the scope when `precision` is Bf16 (nothing otherwise). Throws
// std::invalid_argument when bf16 is asked for where it cannot run. Clears autocast's weight
// cache when the outermost scope ends, so an optimiser step never meets stale bf16 copies.
class AutocastScope {
 public:
  AutocastScope(Precision precision, const torch::Device& device);
  ~AutocastScope();
  AutocastScope(const AutocastScope&) = delete;
  AutocastScope& operator=(const AutocastScope&) = delete;

 private:
  bool active_ = false;
  bool previous_enabled_ = false;
};

// Applies a config's [compute] section for `device`: sets the process's attention kernel and CPU split, and
// returns the precision to give the model (AbleNerf::set_precision). InputError naming
// `source` and compute.precision when bf16 cannot run on the device.
Precision apply_compute_config(const ComputeConfig& c, const torch::Device& device, const std::string& source);

}  // namespace ablenerf
