#pragma once
// The input checks the kernels' host wrappers share: each failure is a c10::Error whose message
// names the operation and the argument ("bias_gelu: b must be float32, got BFloat16").
#include <torch/torch.h>

namespace ablenerf::kernel_checks {

inline void cuda(const char* op, const char* name, const torch::Tensor& t) {
  TORCH_CHECK(t.defined(), op, ": ", name, " is undefined");
  TORCH_CHECK(t.is_cuda(), op, ": ", name, " must be a CUDA tensor, got one on ", t.device());
}

inline void contiguous(const char* op, const char* name, const torch::Tensor& t) {
  TORCH_CHECK(t.is_contiguous(), op, ": ", name, " must be contiguous (strides ", t.strides(), ")");
}

inline void dtype(const char* op, const char* name, const torch::Tensor& t, torch::ScalarType want) {
  TORCH_CHECK(t.scalar_type() == want, op, ": ", name, " must be ", want, ", got ", t.scalar_type());
}

// float32 or bfloat16: the activation dtypes the kernels are compiled for.
inline void activation_dtype(const char* op, const char* name, const torch::Tensor& t) {
  TORCH_CHECK(t.scalar_type() == torch::kFloat || t.scalar_type() == torch::kBFloat16, op, ": ", name,
              " must be Float or BFloat16, got ", t.scalar_type());
}

inline void same_device(const char* op, const char* name, const torch::Tensor& t, const torch::Tensor& ref) {
  TORCH_CHECK(t.device() == ref.device(), op, ": ", name, " must be on ", ref.device(), " like x, got ", t.device());
}

// A float32 parameter vector of `size` values on x's device, contiguous.
inline void parameter_vector(const char* op, const char* name, const torch::Tensor& t, int64_t size,
                             const torch::Tensor& x) {
  cuda(op, name, t);
  same_device(op, name, t, x);
  TORCH_CHECK(t.dim() == 1 && t.size(0) == size, op, ": ", name, " must have shape (", size, "), got ", t.sizes());
  dtype(op, name, t, torch::kFloat);
  contiguous(op, name, t);
}

}  // namespace ablenerf::kernel_checks
