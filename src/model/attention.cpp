#include "model/attention.h"

#include <torch/version.h>

#include <cmath>

#include "kernels/block_tail.h"
#include "kernels/packed_attention.h"
#include "model/ab_transformer.h"
#include "model/linear_tokens.h"

#ifdef ABLENERF_CUDA_KERNELS
#include "kernels/bias_gelu.h"
#include "kernels/ray_attention.h"
#include "kernels/residual_layer_norm.h"
#include "model/compute_config.h"
#endif

namespace ablenerf {

namespace {
// Widths the fused LayerNorm kernel takes (kernels/residual_layer_norm.h): a multiple of a warp.
constexpr int64_t kWarp = 32, kMaxFusedWidth = 1024;
// The widest block whose tail runs as kernels/block_tail.h on the CPU: its products are the
// project's register-blocked loops, which pay off for narrow matrices (the capture and demo
// presets' 32 and 48); at the blender preset's 192 (feed-forward 576) the tail's chunked weight
// gradients made the step 20% slower than the plain path's BLAS (docs/benchmarks/history.md, "The block
// tail fused").
constexpr int64_t kMaxFusedTailWidth = 64;
}  // namespace

MultiHeadAttentionImpl::MultiHeadAttentionImpl(int64_t width, int64_t heads) : width_(width), heads_(heads) {
  TORCH_CHECK(width % heads == 0, "attention width must be divisible by the head count");
  in_proj_weight = register_parameter("in_proj_weight", torch::empty({3 * width, width}));
  in_proj_bias = register_parameter("in_proj_bias", torch::empty({3 * width}));
  out_proj = register_module("out_proj", torch::nn::Linear(width, width));
  reset_parameters();
}

void MultiHeadAttentionImpl::reset_parameters() {
  // PyTorch's nn.MultiheadAttention init (docs/MODEL.md, section 8): xavier-uniform over the whole packed
  // matrix, zero in-proj bias, default Linear weight for out_proj with a zero bias.
  torch::NoGradGuard no_grad;
  torch::nn::init::xavier_uniform_(in_proj_weight);
  in_proj_bias.zero_();
  out_proj->reset_parameters();
  out_proj->bias.zero_();
}

bool MultiHeadAttentionImpl::is_ray_mask(const torch::Tensor& mask) {
  if (!mask.defined()) return false;
  if (mask.data_ptr() == ray_mask_seen_) return true;
  if (mask.dim() != 2 || mask.size(0) != mask.size(1)) return false;
  // A synchronising comparison, once per mask tensor (the model holds one).
  const auto cpu = mask.detach().to(torch::kCPU, torch::kFloat);
  if (!torch::equal(cpu, ray_attention_mask(mask.size(0) - 1))) return false;
  ray_mask_seen_ = mask.data_ptr();
  return true;
}

torch::Tensor MultiHeadAttentionImpl::forward_self(const torch::Tensor& x, const torch::Tensor& mask,
                                                   RayQueryProbe* probe, bool project) {
  const auto projected = [&](const torch::Tensor& heads) { return project ? linear_tokens(out_proj, heads) : heads; };
  const int64_t b = x.size(0), l = x.size(1), dh = width_ / heads_;
  const auto packed = linear_tokens(x, in_proj_weight, in_proj_bias);  // (B, L, 3E)
#ifdef ABLENERF_CUDA_KERNELS
  // The project's fused kernel for rays of up to 128 tokens with 64-wide heads, under the ray
  // mask or none; it also returns the ray token's attention row the resampler needs.
  if (kernel_ == AttentionKernel::Fused && x.is_cuda() && ray_attention_supports(l, dh) &&
      (!mask.defined() || is_ray_mask(mask))) {
    const RayAttentionResult r = ray_attention(packed, heads_, mask.defined());
    if (probe && !probe->keep_graph) probe->row0 = r.row0;
    if (probe && probe->keep_graph) fill_probe(packed, b, l, probe);
    return projected(r.out);
  }
#endif
  if (kernel_ == AttentionKernel::Fused && packed_attention_available(x)) {
    if (!probe) return projected(packed_self_attention(packed, heads_, mask, scale()));
    // The kernel's own row of the ray token, attached to the graph when the probe keeps it.
    const PackedAttention r = packed_self_attention_row0(packed, heads_, mask, scale());
    probe->row0 = probe->keep_graph ? r.row0 : r.row0.detach();
    return projected(r.out);
  }
  if (probe) fill_probe(packed, b, l, probe);
  // (B,L,3,H,dh) -> (3,B,H,L,dh): views, no copy.
  const auto qkv = packed.view({b, l, 3, heads_, dh}).permute({2, 0, 3, 1, 4});
  return projected(attend(qkv[0], qkv[1], qkv[2], mask));
}

void MultiHeadAttentionImpl::fill_probe(const torch::Tensor& packed, int64_t b, int64_t l, RayQueryProbe* probe) const {
  // (B,L,3,H,dh) views, no copy.
  const auto heads = packed.view({b, l, 3, heads_, width_ / heads_});
  const auto q0 = heads.select(1, 0).select(1, 0);          // (B,H,dh)
  const auto k = heads.select(2, 1).permute({0, 2, 1, 3});  // (B,H,L,dh)
  probe->q0 = probe->keep_graph ? q0 : q0.detach();
  probe->k = probe->keep_graph ? k : k.detach();
}

void MultiHeadAttentionImpl::fill_probe_cross(const torch::Tensor& q_heads, const torch::Tensor& kv_heads,
                                              RayQueryProbe* probe) const {
  probe->q0 = probe->keep_graph ? q_heads.select(2, 0) : q_heads.select(2, 0).detach();
  probe->k = probe->keep_graph ? kv_heads[0] : kv_heads[0].detach();
}

torch::Tensor MultiHeadAttentionImpl::forward_cross(const torch::Tensor& q_in, const torch::Tensor& kv_in,
                                                    RayQueryProbe* probe, bool project) {
  const auto projected = [&](const torch::Tensor& heads) { return project ? linear_tokens(out_proj, heads) : heads; };
  const int64_t dh = width_ / heads_;
  // One split per parameter, not two slices: its backward is one concatenation of the two parts'
  // gradients, where each slice's would fill a gradient of the whole parameter and add them.
  const auto w = in_proj_weight.split_with_sizes({width_, 2 * width_}, 0);
  const auto b = in_proj_bias.split_with_sizes({width_, 2 * width_}, 0);
  const auto &wq = w[0], &wkv = w[1], &bq = b[0], &bkv = b[1];
  const auto q = linear_tokens(q_in, wq, bq);      // (Bq, Lq, E)
  const auto kv = linear_tokens(kv_in, wkv, bkv);  // (B, Lk, 2E)
  const auto kv_heads = kv.view({kv_in.size(0), kv_in.size(1), 2, heads_, dh}).permute({2, 0, 3, 1, 4});
  const auto q_heads = q.view({q_in.size(0), q_in.size(1), heads_, dh}).transpose(1, 2);
  if (kernel_ == AttentionKernel::Fused && packed_attention_available(q_in)) {
    // The kernel's own row for per-ray queries (the ray token's); shared queries fill q0 and k.
    if (probe && q.size(0) == kv.size(0)) {
      const PackedAttention r = packed_cross_attention_row0(q, kv, heads_, scale());
      probe->row0 = probe->keep_graph ? r.row0 : r.row0.detach();
      return projected(r.out);
    }
    if (probe) fill_probe_cross(q_heads, kv_heads, probe);
    return projected(packed_cross_attention(q, kv, heads_, scale()));
  }
  if (probe) fill_probe_cross(q_heads, kv_heads, probe);
  return projected(attend(q_heads, kv_heads[0], kv_heads[1], torch::Tensor()));
}

double MultiHeadAttentionImpl::scale() const { return 1.0 / std::sqrt(static_cast<double>(width_ / heads_)); }

torch::Tensor MultiHeadAttentionImpl::attend(const torch::Tensor& q_in, const torch::Tensor& k, const torch::Tensor& v,
                                             const torch::Tensor& mask) {
  const int64_t b = k.size(0), lq = q_in.size(2), dh = width_ / heads_;
  const auto q = q_in.expand({b, heads_, lq, dh});
  torch::Tensor o;
#if TORCH_VERSION_MAJOR >= 2
  if (kernel_ == AttentionKernel::Fused) {
    // Fused kernels (flash / memory-efficient on CUDA); the shared (L,L) mask broadcasts over rays
    // and heads. Queries shared by the batch (LE cross-attention) are materialised: the kernels
    // want a real batch stride.
    const auto qc = q_in.size(0) == b ? q : q.contiguous();
    o = mask.defined() ? at::scaled_dot_product_attention(qc, k, v, mask) : at::scaled_dot_product_attention(qc, k, v);
  }
#endif
  if (!o.defined()) {
    // The reference: explicit scores, additive mask, softmax, weighted sum.
    auto scores = torch::matmul(q, k.transpose(-2, -1)) * scale();
    if (mask.defined()) scores = scores + mask;
    o = torch::matmul(torch::softmax(scores, -1), v);
  }
  return o.transpose(1, 2).reshape({b, lq, width_});
}

TransformerBlockImpl::TransformerBlockImpl(int64_t width, int64_t heads, int64_t ff_width) {
  attn = register_module("attn", MultiHeadAttention(width, heads));
  ff_in = register_module("ff_in", torch::nn::Linear(width, ff_width));
  ff_out = register_module("ff_out", torch::nn::Linear(ff_width, width));
  const auto ln = torch::nn::LayerNormOptions({width}).eps(kLayerNormEps);
  norm1 = register_module("norm1", torch::nn::LayerNorm(ln));
  norm2 = register_module("norm2", torch::nn::LayerNorm(ln));
}

torch::Tensor TransformerBlockImpl::finish(const torch::Tensor& x, const torch::Tensor& attn_out) {
#ifdef ABLENERF_CUDA_KERNELS
  // On CUDA with the fused kernels: residual add + LayerNorm and bias + GELU in one kernel each,
  // activations kept in the products' dtype (bf16 under autocast) instead of fp32 LayerNorm
  // outputs that every following product casts again.
  const int64_t width = x.size(-1);
  if (attn->kernel() == AttentionKernel::Fused && x.is_cuda() && width % kWarp == 0 && width <= kMaxFusedWidth) {
    const auto dtype = attn_out.scalar_type();
    // Queries shared by the batch (the LE's, batch 1) are materialised per ray, as the plain
    // path's broadcasting add would.
    const auto residual = x.sizes() == attn_out.sizes() ? x : x.expand_as(attn_out);
    const auto h = residual_layer_norm(residual.to(dtype).contiguous(), attn_out.contiguous(), norm1->weight,
                                       norm1->bias, kLayerNormEps);
    const auto hidden = bias_gelu(linear_tokens(ff_in, h, /*with_bias=*/false).contiguous(), ff_in->bias);
    const auto ff = linear_tokens(ff_out, hidden.to(dtype));
    return residual_layer_norm(h, ff.to(dtype).contiguous(), norm2->weight, norm2->bias, kLayerNormEps);
  }
#endif
  const auto h = norm1(x + attn_out);
  // GELU default = exact erf form (PyTorch's default, used by the release).
  const auto ff = linear_tokens(ff_out, torch::gelu(linear_tokens(ff_in, h)));
  return norm2(h + ff);
}

bool TransformerBlockImpl::fused_tail(const torch::Tensor& x) const {
  return attn->kernel() == AttentionKernel::Fused && x.device().is_cpu() && x.scalar_type() == torch::kFloat &&
         x.size(-1) <= kMaxFusedTailWidth && attn->in_proj_weight.device().is_cpu() &&
         attn->in_proj_weight.scalar_type() == torch::kFloat;
}

torch::Tensor TransformerBlockImpl::fused_finish(const torch::Tensor& x, const torch::Tensor& heads) {
  const BlockTailWeights w{attn->out_proj->weight, attn->out_proj->bias, norm1->weight,  norm1->bias,
                           ff_in->weight,          ff_in->bias,          ff_out->weight, ff_out->bias,
                           norm2->weight,          norm2->bias};
  return block_tail(x, heads, w, kLayerNormEps);
}

torch::Tensor TransformerBlockImpl::forward_self(const torch::Tensor& x, const torch::Tensor& mask,
                                                 RayQueryProbe* probe) {
  if (fused_tail(x)) return fused_finish(x, attn->forward_self(x, mask, probe, /*project=*/false));
  return finish(x, attn->forward_self(x, mask, probe));
}

torch::Tensor TransformerBlockImpl::forward_cross(const torch::Tensor& q, const torch::Tensor& kv,
                                                  RayQueryProbe* probe) {
  if (fused_tail(q)) return fused_finish(q, attn->forward_cross(q, kv, probe, /*project=*/false));
  return finish(q, attn->forward_cross(q, kv, probe));
}

torch::Tensor TransformerBlockImpl::forward_first(const torch::Tensor& x, RayQueryProbe* probe) {
  return forward_cross(x.slice(1, 0, 1), x, probe);
}

}  // namespace ablenerf
