#pragma once
// How the model's arithmetic runs, without changing what it computes:
//  - the attention kernel: "fused" = on the CPU the direct-BLAS kernel over the packed projections
//    (kernels/packed_attention.h) and, in blocks up to 64 wide, each block's tail after it as one
//    node (kernels/block_tail.h: output projection, residual, LayerNorm, feed-forward, residual,
//    LayerNorm); on CUDA the project's ray-attention kernel where it applies
//    (kernels/ray_attention.h), else scaled_dot_product_attention (LibTorch >= 2), and the
//    project's residual + LayerNorm and bias + GELU kernels in every transformer block;
//    "plain" = explicit softmax(Q K^T / sqrt(d) + mask) V and LibTorch's own ops;
//  - the precision of the matrix products: "fp32", or "bf16": on CUDA autocast to bfloat16, on a
//    CPU with AMX tiles the transformer's token products (the linear layers' and the block tails'
//    forward and input-gradient products: kernels/token_product.h) with bfloat16 operands and
//    float32 sums; the weights, the loss and the optimiser kept in fp32 either way; or "auto" =
//    bf16 where it runs (a CUDA device with LibTorch >= 2, a CPU with AMX), fp32 elsewhere;
//  - how CPU threads share the work: "rays" = a slice of the rays per thread through the whole
//    model (kernels/cpu_parallel.h), "ops" = threads only inside each op or product.
// A model owns its Compute (AbleNerf::set_compute), so two models in one process (a benchmark's
// reference and fast variants) never share a switch.
#include <torch/torch.h>

#include <optional>
#include <string>

#include "kernels/token_product.h"
#include "model/compute_config.h"

namespace ablenerf {

struct Compute {
  AttentionKernel attention = AttentionKernel::Fused;
  Precision precision = Precision::Fp32;
  CpuSplit cpu_split = CpuSplit::Rays;

  // A config's [compute] section for `device`, "auto" resolved to fp32 or bf16 (a Compute holds
  // one of those two). InputError naming `source` and compute.precision when bf16 cannot run on
  // the device; with `bf16_falls_back` bf16 becomes fp32 there instead (a run trained in bf16 on a
  // GPU still renders on a CPU).
  static Compute from_config(const ComputeConfig& c, const torch::Device& device, const std::string& source,
                             bool bf16_falls_back = false);
};

// True when bf16 autocast can run on `device` (a CUDA device, LibTorch >= 2).
bool bf16_autocast_available(const torch::Device& device);
// True when compute.precision = "bf16" runs on `device`: autocast there, or a CPU with AMX.
bool bf16_available(const torch::Device& device);

// `t` as CUDA autocast hands it to a matrix product: inside a bf16 scope on CUDA cast to bf16 (a
// weight through autocast's cache, so once per scope), elsewhere unchanged. For the products an
// autograd function of the project runs itself (autocast cannot see inside it).
torch::Tensor autocast_product_operand(const torch::Tensor& t);

// bf16 autocast on CUDA, bfloat16 token products on a CPU (TokenProductsBf16Scope), for the scope
// when `precision` is Bf16 (nothing otherwise). Throws
// std::invalid_argument when bf16 is asked for where it cannot run. Nested scopes share the
// outermost one's weight cache (each weight is cast once per outermost scope, e.g. once per
// training step); the cache is cleared when the outermost scope ends, so an optimiser step never
// meets stale bf16 copies.
class AutocastScope {
 public:
  AutocastScope(Precision precision, const torch::Device& device);
  ~AutocastScope();
  AutocastScope(const AutocastScope&) = delete;
  AutocastScope& operator=(const AutocastScope&) = delete;

 private:
  bool active_ = false;
  bool previous_enabled_ = false;
  std::optional<TokenProductsBf16Scope> cpu_products_;
};

}  // namespace ablenerf
