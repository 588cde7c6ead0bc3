#include "model/compute.h"

#include <torch/version.h>

#include <stdexcept>

#include "util/errors.h"
#include "model/compute_config.h"

#if TORCH_VERSION_MAJOR >= 2
#include <ATen/autocast_mode.h>
// The device-type autocast API arrived in 2.4; 2.0-2.3 only have the CUDA-specific one.
#if TORCH_VERSION_MAJOR > 2 || TORCH_VERSION_MINOR >= 4
#define ABLENERF_AUTOCAST_BY_DEVICE 1
#endif
#endif

namespace ablenerf {

bool bf16_autocast_available(const torch::Device& device) { return TORCH_VERSION_MAJOR >= 2 && device.is_cuda(); }

bool bf16_available(const torch::Device& device) {
  return bf16_autocast_available(device) || (device.is_cpu() && cpu_has_bf16_products());
}

namespace {
std::string bf16_unavailable(const torch::Device& device) {
  return std::string("bf16 needs a CUDA device with LibTorch >= 2 or a CPU with AMX bfloat16 tiles (device ") +
         device.str() + ", LibTorch " + TORCH_VERSION + ")";
}
}  // namespace

torch::Tensor autocast_product_operand(const torch::Tensor& t) {
  if (!t.defined() || !t.is_cuda()) return t;
#if TORCH_VERSION_MAJOR >= 2
#ifdef ABLENERF_AUTOCAST_BY_DEVICE
  if (at::autocast::is_autocast_enabled(at::kCUDA))
    return at::autocast::cached_cast(at::autocast::get_autocast_dtype(at::kCUDA), t, at::kCUDA);
#else
  if (at::autocast::is_enabled()) return at::autocast::cached_cast(at::autocast::get_autocast_gpu_dtype(), t);
#endif
#endif
  return t;
}

AutocastScope::AutocastScope(Precision precision, const torch::Device& device) {
  if (precision != Precision::Bf16) return;
  if (!bf16_available(device)) throw std::invalid_argument(bf16_unavailable(device));
  if (device.is_cpu()) {
    cpu_products_.emplace(true);
    return;
  }
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

Compute Compute::from_config(const ComputeConfig& c, const torch::Device& device, const std::string& source,
                             bool bf16_falls_back) {
  Compute out{c.attention, c.precision, c.cpu_split};
  if (out.precision == Precision::Auto) out.precision = bf16_available(device) ? Precision::Bf16 : Precision::Fp32;
  if (out.precision == Precision::Bf16 && !bf16_available(device)) {
    if (!bf16_falls_back) throw InputError(source, "compute.precision", bf16_unavailable(device) + "; use fp32");
    out.precision = Precision::Fp32;
  }
  return out;
}

}  // namespace ablenerf
