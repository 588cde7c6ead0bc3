#pragma once
// Stage 4a (docs/MODEL.md, sections 4 and 6): multi-head attention with a packed Q/K/V projection, and the
// post-norm transformer block built on it:
//   x = LN1(x + MHA(x));  x = LN2(x + W2 GELU(W1 x + b1) + b2)
// Attention is written by hand (batch-first (B,L,E) tensors, one mask shared by every ray and
// head) instead of torch::nn::MultiheadAttention, which is sequence-first and would need the
// mask expanded to B x heads copies.
#include <torch/torch.h>

#include "model/compute_config.h"

namespace ablenerf {

// The blocks' LayerNorm epsilon: PyTorch's default, which the authors' release uses.
constexpr double kLayerNormEps = 1e-5;

// What the resampler needs from one self-attention layer: the ray token's (row 0) query and
// every key, detached, so its attention row can be recomputed as one extra query (docs/MODEL.md, section 5)
// without ever materialising per-layer attention matrices for the caller.
struct RayQueryProbe {
  torch::Tensor q0;  // (B,H,dh)
  torch::Tensor k;   // (B,H,L,dh)
  // Or, from a kernel that computes it anyway, the row itself: (B,H,L) softmax probabilities of
  // the ray token over every token. The CPU kernels (kernels/packed_attention.h) return it attached
  // to the graph when keep_graph is set, detached otherwise; the CUDA kernel
  // (kernels/ray_attention.h) only detached, so there q0 and k are filled instead when keep_graph.
  torch::Tensor row0;
  // Set by the caller: keep the row attached to the graph, so that a loss on the attention row
  // reaches the weights (train.distortion_weight, train.proposal_attention_weight).
  bool keep_graph = false;
};

class MultiHeadAttentionImpl : public torch::nn::Module {
 public:
  MultiHeadAttentionImpl(int64_t width, int64_t heads);
  // Self-attention. x: (B,L,E); mask: additive (L,L) (0 = may attend, -inf = blocked) or
  // undefined for none. Fills `probe` when given. With `project` false the result is the
  // concatenated heads before the output projection (for a caller that fuses it with what follows).
  torch::Tensor forward_self(const torch::Tensor& x, const torch::Tensor& mask, RayQueryProbe* probe = nullptr,
                             bool project = true);
  // Cross-attention without mask. q: (Bq,Lq,E) with Bq == B or 1 (broadcast); kv: (B,Lk,E).
  // Fills `probe` (q0 = the first query) when given. `project` as for forward_self.
  torch::Tensor forward_cross(const torch::Tensor& q, const torch::Tensor& kv, RayQueryProbe* probe = nullptr,
                              bool project = true);
  void reset_parameters();
  // Which attention kernel this layer runs (model/compute.h); set by AbleNerf::set_compute.
  void set_kernel(AttentionKernel kernel) { kernel_ = kernel; }
  AttentionKernel kernel() const { return kernel_; }

  torch::Tensor in_proj_weight;  // (3E,E): rows [0,E) Q, [E,2E) K, [2E,3E) V
  torch::Tensor in_proj_bias;    // (3E)
  torch::nn::Linear out_proj{nullptr};

 private:
  double scale() const;  // 1/sqrt(head width)
  // The probe's q0 and k from the packed projections (B,L,3E) of a self-attention.
  void fill_probe(const torch::Tensor& packed, int64_t b, int64_t l, RayQueryProbe* probe) const;
  // The same from cross-attention's heads: q (Bq,H,Lq,dh) and kv (2,B,H,Lk,dh).
  void fill_probe_cross(const torch::Tensor& q_heads, const torch::Tensor& kv_heads, RayQueryProbe* probe) const;
  // q: (Bq,H,Lq,dh), k, v: (B,H,Lk,dh) -> (B,Lq,E), the heads concatenated (no output projection).
  torch::Tensor attend(const torch::Tensor& q, const torch::Tensor& k, const torch::Tensor& v,
                       const torch::Tensor& mask);
  // True when `mask` is the ray mask of kernels/ray_attention.h (checked once per mask tensor).
  bool is_ray_mask(const torch::Tensor& mask);

  int64_t width_, heads_;
  AttentionKernel kernel_ = AttentionKernel::Fused;
  const void* ray_mask_seen_ = nullptr;  // the last mask found to be the ray mask
};
TORCH_MODULE(MultiHeadAttention);

class TransformerBlockImpl : public torch::nn::Module {
 public:
  TransformerBlockImpl(int64_t width, int64_t heads, int64_t ff_width);
  torch::Tensor forward_self(const torch::Tensor& x, const torch::Tensor& mask, RayQueryProbe* probe = nullptr);
  // q may have batch 1 (shared queries, e.g. the LE); the result has kv's batch.
  torch::Tensor forward_cross(const torch::Tensor& q, const torch::Tensor& kv, RayQueryProbe* probe = nullptr);
  // Row 0 of forward_self, (B,1,E), for a mask whose row 0 blocks nothing (the ray token's): the
  // first token attends to every token, so only its query, its output projection and its
  // feed-forward are computed. Fills `probe` like forward_self.
  torch::Tensor forward_first(const torch::Tensor& x, RayQueryProbe* probe = nullptr);

  MultiHeadAttention attn{nullptr};
  torch::nn::Linear ff_in{nullptr}, ff_out{nullptr};
  torch::nn::LayerNorm norm1{nullptr}, norm2{nullptr};

 private:
  torch::Tensor finish(const torch::Tensor& x, const torch::Tensor& attn_out);
  // True when the tail after the attention core runs as kernels/block_tail.h (CPU float32 under
  // compute.attention = "fused", blocks up to 64 wide): the attention then returns its heads
  // unprojected.
  bool fused_tail(const torch::Tensor& x) const;
  // The tail on the attention's concatenated heads (B,L,E): kernels/block_tail.h.
  torch::Tensor fused_finish(const torch::Tensor& x, const torch::Tensor& heads);
};
TORCH_MODULE(TransformerBlock);

}  // namespace ablenerf
