#pragma once
// A Linear applied to token tensors as one 2-D product with the bias fused into it:
// x (..., in) -> (..., out). A 3-D input to torch::nn::Linear would otherwise go through matmul
// and a separate bias add. CPU float32 runs kernels/linear_cpu.h (one autograd node), elsewhere
// ATen's addmm, with the bias gradient as a product with a ones row rather than a column
// reduction (the reduction was a sixth of the GPU's training step). Shared by the volume embedding, attention's
// projections and the feed-forward layers.
#include <torch/torch.h>

namespace ablenerf {

// with_bias = false leaves the bias out (for a kernel that adds it in its own epilogue).
torch::Tensor linear_tokens(const torch::nn::Linear& layer, const torch::Tensor& x, bool with_bias = true);

// The same with the weight (out, in) and bias (out, or undefined) given directly (attention's packed
// in-projection and its row slices).
torch::Tensor linear_tokens(const torch::Tensor& x, const torch::Tensor& weight, const torch::Tensor& bias);

// torch::relu(linear_tokens(layer, x)): on the CPU in float32 one node (kernels/linear_cpu.h).
// The MLPs' hidden layers (the volume embedding, the proposal field).
torch::Tensor linear_relu_tokens(const torch::nn::Linear& layer, const torch::Tensor& x);

}  // namespace ablenerf
