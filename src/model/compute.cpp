#include "model/compute.h"

#include <torch/version.h>

#include <atomic>
#include <stdexcept>

#include "util/errors.h"

#if TORCH_VERSION_MAJOR >= 2
#include <ATen/autocast_mode.h>
// The device-type autocast API arrived in 2.4; 2.0-2.3 only have the CUDA-specific one.
#if TORCH_VERSION_MAJOR > 2 || TORCH_VERSION_MINOR >= 4
#define ABLENERF_AUTOCAST_BY_DEVICE 1
#endif
#endif

namespace ablenerf {

AttentionKernel parse_attention_kernel(const std::string& name) {
  if (name == "fused") return AttentionKernel::Fused;
  if (name == "plain") return AttentionKernel::Plain;
  throw std::invalid_argument("expected 'fused' or 'plain', got '" + name + "'");
}

Precision parse_precision(const std::string& name) {
  if (name == "fp32") return Precision::Fp32;
  if (name == "bf16") return Precision::Bf16;
  throw std::invalid_argument("expected 'fp32' or 'bf16', got '" + name + "'");
}

CpuSplit parse_cpu_split(const std::string& name) {
  if (name == "rays") return CpuSplit::Rays;
  if (name == "ops") return CpuSplit::Ops;
  throw std::invalid_argument("expected 'rays' or 'ops', got '" + name + "'");
}

const char* to_string(AttentionKernel k) { return k == AttentionKernel::Fused ? "fused" : "plain"; }
const char* to_string(Precision p) { return p == Precision::Bf16 ? "bf16" : "fp32"; }

bool fused_attention_compiled() { return TORCH_VERSION_MAJOR >= 2; }

namespace {
std::atomic<AttentionKernel> g_attention_kernel{AttentionKernel::Fused};
std::atomic<CpuSplit> g_cpu_split{CpuSplit::Rays};
}  // namespace

void set_cpu_split(CpuSplit split) { g_cpu_split.store(split); }
CpuSplit cpu_split() { return g_cpu_split.load(); }

void set_attention_kernel(AttentionKernel kernel) { g_attention_kernel.store(kernel); }
AttentionKernel attention_kernel() { return g_attention_kernel.load(); }

bool bf16_autocast_available(const torch::Device& device) {
  return TORCH_VERSION_MAJOR >= 2 && device.is_cuda();
}

AutocastScope::AutocastScope(Precision precision, const torch::Device& device) {
  if (precision != Precision::Bf16) return;
  if (!bf16_autocast_available(device))
    throw std::invalid_argument(std::string("bf16 needs a CUDA device and LibTorch >= 2 (device: ") + device.str() +
                                ", LibTorch " + TORCH_VERSION + ")");
#if TORCH_VERSION_MAJOR >= 2
#ifdef ABLENERF_AUTOCAST_BY_DEVICE
  previous_enabled_ = at::autocast::is_autocast_enabled(at::kCUDA);
  at::autocast::set_autocast_dtype(at::kCUDA, at::kBFloat16);
  at::autocast::set_autocast_enabled(at::kCUDA, true);
#else
  previous_enabled_ = at::autocast::is_enabled();
  at::autocast::set_autocast_gpu_dtype(at::kBFloat16);
  at::autocast::set_enabled(true);
#endif
  at::autocast::increment_nesting();
  active_ = true;
#endif
}

AutocastScope::~AutocastScope() {
#if TORCH_VERSION_MAJOR >= 2
  if (!active_) return;
  if (at::autocast::decrement_nesting() == 0) at::autocast::clear_cache();
#ifdef ABLENERF_AUTOCAST_BY_DEVICE
  at::autocast::set_autocast_enabled(at::kCUDA, previous_enabled_);
#else
  at::autocast::set_enabled(previous_enabled_);
#endif
#endif
}

Precision apply_compute_config(const ComputeConfig& c, const torch::Device& device, const std::string& source) {
  Precision p;
  try {
    set_attention_kernel(parse_attention_kernel(c.attention));
    set_cpu_split(parse_cpu_split(c.cpu_split));
    p = parse_precision(c.precision);
  } catch (const std::invalid_argument& e) {
    throw InputError(source, "compute", e.what());
  }
  if (p == Precision::Bf16 && !bf16_autocast_available(device))
    throw InputError(source, "compute.precision",
                     "bf16 needs a CUDA device and LibTorch >= 2 (device " + device.str() + ", LibTorch " +
                         TORCH_VERSION + "); use fp32");
  return p;
}

}  // namespace ablenerf
