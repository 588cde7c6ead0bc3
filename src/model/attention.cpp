#include "model/attention.h"

#include <torch/version.h>

#include <cmath>

#include "model/attention_core.h"
#include "model/compute.h"
#include "model/volume_embedding.h"

namespace ablenerf {

namespace {
constexpr double kLayerNormEps = 1e-5;  // PyTorch default, used by the release
}  // namespace

MultiHeadAttentionImpl::MultiHeadAttentionImpl(int64_t width, int64_t heads)
    : width_(width), heads_(heads) {
  TORCH_CHECK(width % heads == 0, "attention width must be divisible by the head count");
  in_proj_weight = register_parameter("in_proj_weight", torch::empty({3 * width, width}));
  in_proj_bias = register_parameter("in_proj_bias", torch::empty({3 * width}));
  out_proj = register_module("out_proj", torch::nn::Linear(width, width));
  reset_parameters();
}

void MultiHeadAttentionImpl::reset_parameters() {
  // PyTorch's nn.MultiheadAttention init (spec 8.1): xavier-uniform over the whole packed
  // matrix, zero in-proj bias, default Linear weight for out_proj with a zero bias.
  torch::NoGradGuard no_grad;
  torch::nn::init::xavier_uniform_(in_proj_weight);
  in_proj_bias.zero_();
  out_proj->reset_parameters();
  out_proj->bias.zero_();
}

torch::Tensor MultiHeadAttentionImpl::forward_self(const torch::Tensor& x, const torch::Tensor& mask,
                                                   RayQueryProbe* probe) {
  const int64_t b = x.size(0), l = x.size(1), dh = width_ / heads_;
  const auto flat = x.reshape({-1, width_});
  // (B,L,3,H,dh) -> (3,B,H,L,dh): views, no copy.
  const auto qkv = torch::addmm(in_proj_bias, flat, in_proj_weight.t())
                       .view({b, l, 3, heads_, dh})
                       .permute({2, 0, 3, 1, 4});
  const auto q = qkv[0], k = qkv[1], v = qkv[2];
  if (probe) {
    probe->q0 = q.select(2, 0).detach();
    probe->k = k.detach();
  }
  return attend(q, k, v, mask);
}

torch::Tensor MultiHeadAttentionImpl::forward_cross(const torch::Tensor& q_in, const torch::Tensor& kv_in,
                                                    RayQueryProbe* probe) {
  const int64_t dh = width_ / heads_;
  const auto wq = in_proj_weight.slice(0, 0, width_), bq = in_proj_bias.slice(0, 0, width_);
  const auto wkv = in_proj_weight.slice(0, width_), bkv = in_proj_bias.slice(0, width_);
  const auto q = torch::addmm(bq, q_in.reshape({-1, width_}), wq.t())
                     .view({q_in.size(0), q_in.size(1), heads_, dh})
                     .transpose(1, 2);
  const auto kv = torch::addmm(bkv, kv_in.reshape({-1, width_}), wkv.t())
                      .view({kv_in.size(0), kv_in.size(1), 2, heads_, dh})
                      .permute({2, 0, 3, 1, 4});
  if (probe) {
    probe->q0 = q.select(2, 0).detach();
    probe->k = kv[0].detach();
  }
  return attend(q, kv[0], kv[1], torch::Tensor());
}

torch::Tensor MultiHeadAttentionImpl::attend(const torch::Tensor& q_in, const torch::Tensor& k,
                                             const torch::Tensor& v, const torch::Tensor& mask) {
  const int64_t b = k.size(0), lq = q_in.size(2), lk = k.size(2), dh = width_ / heads_;
  const auto q = q_in.expand({b, heads_, lq, dh});
  const double scale = 1.0 / std::sqrt(static_cast<double>(dh));
  torch::Tensor o;
#if TORCH_VERSION_MAJOR >= 2
  if (attention_kernel() == AttentionKernel::Fused) {
    // Fused kernels (flash / memory-efficient on CUDA); the shared (L,L) mask broadcasts over rays
    // and heads. Queries shared by the batch (LE cross-attention) are materialised: the kernels
    // want a real batch stride.
    const auto qc = q_in.size(0) == b ? q : q.contiguous();
    o = mask.defined() ? at::scaled_dot_product_attention(qc, k, v, mask) : at::scaled_dot_product_attention(qc, k, v);
  }
#endif
  if (!o.defined()) {
    if (q.device().is_cpu() && q.scalar_type() == torch::kFloat && k.scalar_type() == torch::kFloat) {
      // Many small products (one per ray and head), split across threads by attention_core; the
      // shared (L,L) mask is broadcast, never copied per ray or head.
      o = attention_core(q.reshape({b * heads_, lq, dh}), k.reshape({b * heads_, lk, dh}),
                         v.reshape({b * heads_, lk, dh}), mask, scale)
              .view({b, heads_, lq, dh});
    } else {
      // The reference: explicit scores, additive mask, softmax, weighted sum.
      auto scores = torch::matmul(q, k.transpose(-2, -1)) * scale;
      if (mask.defined()) scores = scores + mask;
      o = torch::matmul(torch::softmax(scores, -1), v);
    }
  }
  return linear_tokens(out_proj, o.transpose(1, 2).reshape({b, lq, width_}));
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
  const auto h = norm1(x + attn_out);
  // GELU default = exact erf form (PyTorch's default, used by the release).
  const auto ff = linear_tokens(ff_out, torch::gelu(linear_tokens(ff_in, h)));
  return norm2(h + ff);
}

torch::Tensor TransformerBlockImpl::forward_self(const torch::Tensor& x, const torch::Tensor& mask,
                                                 RayQueryProbe* probe) {
  return finish(x, attn->forward_self(x, mask, probe));
}

torch::Tensor TransformerBlockImpl::forward_cross(const torch::Tensor& q, const torch::Tensor& kv,
                                                  RayQueryProbe* probe) {
  return finish(q, attn->forward_cross(q, kv, probe));
}

torch::Tensor TransformerBlockImpl::forward_first(const torch::Tensor& x, RayQueryProbe* probe) {
  return forward_cross(x.slice(1, 0, 1), x, probe);
}

}  // namespace ablenerf
