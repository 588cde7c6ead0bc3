#pragma once
// For the host wrappers of a CUDA build only: ATen tensors as the pointer types of the launch
// headers (at::BFloat16 and CUDA's __nv_bfloat16 have one size and layout), and a dispatch on the
// activation dtype. Include under #ifdef ABLENERF_CUDA_KERNELS.
#include <cuda_bf16.h>
#include <torch/torch.h>

namespace ablenerf::aten_cuda {

inline const float* ptr(const torch::Tensor& t, float) { return t.data_ptr<float>(); }
inline const __nv_bfloat16* ptr(const torch::Tensor& t, at::BFloat16) {
  return reinterpret_cast<const __nv_bfloat16*>(t.data_ptr<at::BFloat16>());
}
inline float* mutable_ptr(torch::Tensor& t, float) { return t.data_ptr<float>(); }
inline __nv_bfloat16* mutable_ptr(torch::Tensor& t, at::BFloat16) {
  return reinterpret_cast<__nv_bfloat16*>(t.data_ptr<at::BFloat16>());
}

// Calls fn(tag) with a value of x's element type: at::BFloat16 for bfloat16, float otherwise (the
// wrappers have checked that x is one of the two). ptr(t, tag) then has the launch's pointer type.
template <class Fn>
void dispatch_activation(const torch::Tensor& x, const Fn& fn) {
  if (x.scalar_type() == torch::kBFloat16)
    fn(at::BFloat16());
  else
    fn(float());
}

}  // namespace ablenerf::aten_cuda
