#pragma once
// A Linear applied to token tensors as one 2-D GEMM with the bias fused into it:
// x (..., in) -> (..., out). A 3-D input to torch::nn::Linear would otherwise go through matmul
// and a separate bias add. Shared by the volume embedding, attention and the feed-forward layers.
#include <torch/torch.h>

namespace ablenerf {

// with_bias = false leaves the bias out (for a kernel that adds it in its own epilogue).
torch::Tensor linear_tokens(const torch::nn::Linear& layer, const torch::Tensor& x, bool with_bias = true);

}  // namespace ablenerf
