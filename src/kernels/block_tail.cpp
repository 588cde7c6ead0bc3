#include "kernels/block_tail.h"

#include <ATen/record_function.h>
#include <algorithm>
#include <cmath>
#include <vector>

#include "kernels/cpu_features.h"
#include "kernels/gelu_cpu.h"
#include "kernels/row_reduce.h"
#include "kernels/bf16_gemm.h"
#include "kernels/small_gemm.h"
#include "kernels/token_product.h"

namespace ablenerf {

// In a named namespace: the unity build compiles this file with the other kernels'.
namespace block_tail_impl {

constexpr const char* kBlockTailOp = "block_tail";
// Floats a chunk's working rows may hold (~512 KiB, half of a small L2) and the chunk's bounds.
constexpr int64_t kChunkFloats = 128 * 1024, kMinChunkRows = 16, kMaxChunkRows = 1024;

// The shapes of one call: rows = B * L tokens, E features, F hidden features; the residual x has
// rows_x = Bx * L rows (rows_x == L when its batch of one is shared by every ray).
struct TailShape {
  int64_t rows, rows_x, tokens, e, f;
  int64_t residual_row(int64_t r) const { return rows_x == rows ? r : r % tokens; }
};

int64_t default_chunk_rows(int64_t e, int64_t f) {
  return std::clamp(kChunkFloats / (7 * e + 4 * f), kMinChunkRows, kMaxChunkRows);
}

// C (m x n) += A (m x n).
ABLENERF_ALWAYS_INLINE void add_into(float* __restrict c, const float* __restrict a, int64_t count) {
  for (int64_t i = 0; i < count; ++i) c[i] += a[i];
}

// Column sums of a (rows x n) added into acc (n).
ABLENERF_ALWAYS_INLINE void add_column_sums(float* acc, const float* a, int64_t rows, int64_t n) {
  for (int64_t i = 0; i < rows; ++i) add_into(acc, a + i * n, n);
}

// acc (m x n) += a^T b for a (rows x m), b (rows x n): a weight's gradient over one chunk, in
// float32 or (`bf16`) with bfloat16 operands, b packed into `packed`.
void add_transposed_product(float* acc, const float* a, int64_t m, const float* b, int64_t n, int64_t rows,
                            std::vector<float>& scratch, bool bf16, Bf16Operand& packed) {
  scratch.resize(static_cast<size_t>(m * n));
  if (bf16) {
    packed.pack(b, rows, n, n, 1);
    bf16_gemm_at(m, a, m, packed, scratch.data(), n);
  } else {
    small_gemm(true, m, n, rows, 1.0f, a, m, b, n, scratch.data(), n);
  }
  add_into(acc, scratch.data(), m * n);
}

// LayerNorm of n rows of E in place into their normalised form; rstd[i * stride] = 1 / sqrt(var +
// eps). In passes: each row centred and its variance taken, then every row's reciprocal deviation
// (independent square roots, not one latency chain per row), then the scaling.
ABLENERF_ALWAYS_INLINE void normalise_rows(float* rows, int64_t n, int64_t e, double eps, float* rstd, int64_t stride) {
  for (int64_t i = 0; i < n; ++i) {
    float* s = rows + i * e;
    const float mean = row_sum(s, e) / float(e);
    for (int64_t j = 0; j < e; ++j) s[j] -= mean;
    rstd[i * stride] = row_dot(s, s, e) / float(e);
  }
  for (int64_t i = 0; i < n; ++i) rstd[i * stride] = float(1.0 / std::sqrt(double(rstd[i * stride]) + eps));
  for (int64_t i = 0; i < n; ++i) {
    float* s = rows + i * e;
    const float r = rstd[i * stride];
    for (int64_t j = 0; j < e; ++j) s[j] *= r;
  }
}

// LayerNorm's backward of one row: dy (E) the output's gradient, xhat the normalised row, gamma the
// scale. Writes the input's gradient into dx and adds the parameters' gradients into dgamma, dbeta.
ABLENERF_ALWAYS_INLINE void layer_norm_backward_row(const float* __restrict dy, const float* __restrict xhat,
                                                    const float* __restrict gamma, float rstd, int64_t e,
                                                    float* __restrict dx, float* __restrict dgamma,
                                                    float* __restrict dbeta) {
  for (int64_t j = 0; j < e; ++j) {
    dx[j] = dy[j] * gamma[j];
    dgamma[j] += dy[j] * xhat[j];
    dbeta[j] += dy[j];
  }
  const float mean_g = row_sum(dx, e) / float(e), mean_gx = row_dot(dx, xhat, e) / float(e);
  for (int64_t j = 0; j < e; ++j) dx[j] = rstd * (dx[j] - mean_g - xhat[j] * mean_gx);
}

// Raw pointers to the parameters, with the transposed copies the forward's products read.
// Which products a TailParams prepares its weights for.
enum class TailPass { Forward, Backward };

struct TailParams {
  const float *wo, *bo, *g1, *be1, *w1, *b1, *w2, *b2, *g2, *be2;
  // The three weights as the pass's product operands (kernels/token_product.h): forward
  // heads Wo^T, h W1^T, g W2^T; backward d1 Wo, da1 W1, d2 W2.
  WeightOperand wo_op, w1_op, w2_op;
  bool bf16;  // every product with bfloat16 operands, the weights' gradients' too
  TailParams(const BlockTailWeights& w, const TailShape& s, TailPass pass, bool bf16_products)
      : wo(w.out_weight.data_ptr<float>()),
        bo(w.out_bias.data_ptr<float>()),
        g1(w.norm1_weight.data_ptr<float>()),
        be1(w.norm1_bias.data_ptr<float>()),
        w1(w.ff_in_weight.data_ptr<float>()),
        b1(w.ff_in_bias.data_ptr<float>()),
        w2(w.ff_out_weight.data_ptr<float>()),
        b2(w.ff_out_bias.data_ptr<float>()),
        g2(w.norm2_weight.data_ptr<float>()),
        be2(w.norm2_bias.data_ptr<float>()),
        bf16(bf16_products) {
    const auto use = pass == TailPass::Forward ? WeightOperand::Use::Transposed : WeightOperand::Use::AsIs;
    wo_op.prepare(wo, s.e, s.e, use, bf16_products);
    w1_op.prepare(w1, s.f, s.e, use, bf16_products);
    w2_op.prepare(w2, s.e, s.f, use, bf16_products);
  }
};

// What the forward keeps for the backward, per token: LN1's and LN2's normalised rows (E each),
// the feed-forward's GELU output and GELU's derivative at its input (F each), both reciprocal
// deviations. Full-size tensors under autograd; without it one chunk's worth, reused.
struct TailSaved {
  torch::Tensor xhat1, g, dgelu, xhat2, rstd;  // (R, E), (R, F), (R, F), (R, E), (R, 2)
};

// The forward of rows [lo, hi): y's rows and the saved values (at their rows, or at row 0 of
// chunk-sized buffers when `chunk_saved`).
ABLENERF_ALWAYS_INLINE void forward_chunk_body(const TailShape& s, const TailParams& p, double eps, const float* x,
                                               const float* heads, TailSaved& sv, bool chunk_saved, float* y,
                                               int64_t lo, int64_t hi, std::vector<float>& h_buf,
                                               std::vector<float>& a_buf) {
  const int64_t n = hi - lo, e = s.e, f = s.f, base = chunk_saved ? 0 : lo;
  float* xhat1 = sv.xhat1.data_ptr<float>() + base * e;
  float* g = sv.g.data_ptr<float>() + base * f;
  float* dgelu = sv.dgelu.data_ptr<float>() + base * f;
  float* xhat2 = sv.xhat2.data_ptr<float>() + base * e;
  float* rstd = sv.rstd.data_ptr<float>() + base * 2;
  h_buf.resize(size_t(n * e));
  a_buf.resize(size_t(n * f));
  float* h = h_buf.data();
  float* a1 = a_buf.data();
  // xhat1 <- heads Wo^T, then + bo + x, normalised; h = xhat1 * g1 + be1.
  p.wo_op.multiply(n, heads + lo * e, e, xhat1, e);
  for (int64_t i = 0; i < n; ++i) {
    float* row = xhat1 + i * e;
    const float* xr = x + s.residual_row(lo + i) * e;
    for (int64_t j = 0; j < e; ++j) row[j] += p.bo[j] + xr[j];
  }
  normalise_rows(xhat1, n, e, eps, rstd, 2);
  for (int64_t i = 0; i < n; ++i)
    for (int64_t j = 0; j < e; ++j) h[i * e + j] = xhat1[i * e + j] * p.g1[j] + p.be1[j];
  // a1 = h W1^T + b1; g = GELU(a1) and GELU'(a1).
  p.w1_op.multiply(n, h, e, a1, f);
  for (int64_t i = 0; i < n; ++i)
    for (int64_t j = 0; j < f; ++j) a1[i * f + j] += p.b1[j];
  gelu_and_derivative(a1, g, dgelu, n * f);
  // xhat2 <- g W2^T + b2 + h, normalised; y = xhat2 * g2 + be2.
  p.w2_op.multiply(n, g, f, xhat2, e);
  float* yc = y + lo * e;
  for (int64_t i = 0; i < n; ++i)
    for (int64_t j = 0; j < e; ++j) xhat2[i * e + j] += p.b2[j] + h[i * e + j];
  normalise_rows(xhat2, n, e, eps, rstd + 1, 2);
  for (int64_t i = 0; i < n; ++i)
    for (int64_t j = 0; j < e; ++j) yc[i * e + j] = xhat2[i * e + j] * p.g2[j] + p.be2[j];
}

// The gradients the backward accumulates over chunks (each zeroed once per call).
struct TailGrads {
  std::vector<float> wo, bo, g1, be1, w1, b1, w2, b2, g2, be2;
  explicit TailGrads(const TailShape& s)
      : wo(size_t(s.e * s.e)),
        bo(size_t(s.e)),
        g1(size_t(s.e)),
        be1(size_t(s.e)),
        w1(size_t(s.f * s.e)),
        b1(size_t(s.f)),
        w2(size_t(s.e * s.f)),
        b2(size_t(s.e)),
        g2(size_t(s.e)),
        be2(size_t(s.e)) {}
};

// Scratch of one backward chunk.
struct BackwardScratch {
  std::vector<float> d2, dg, dh, h, product;
  Bf16Operand packed;  // a weight gradient's second operand in bfloat16
};

// The backward of rows [lo, hi): dx's and dheads' rows (dx added into: several rows share one
// residual row when x is shared by the batch), and the weights' gradients added into `gr`.
ABLENERF_ALWAYS_INLINE void backward_chunk_body(const TailShape& s, const TailParams& p, const float* heads,
                                                const TailSaved& sv, const float* dy, float* dx, float* dheads,
                                                TailGrads& gr, int64_t lo, int64_t hi, BackwardScratch& t) {
  const int64_t n = hi - lo, e = s.e, f = s.f;
  const float* xhat1 = sv.xhat1.data_ptr<float>() + lo * e;
  const float* g = sv.g.data_ptr<float>() + lo * f;
  const float* dgelu = sv.dgelu.data_ptr<float>() + lo * f;
  const float* xhat2 = sv.xhat2.data_ptr<float>() + lo * e;
  const float* rstd = sv.rstd.data_ptr<float>() + lo * 2;
  const float* dyc = dy + lo * e;
  t.d2.resize(size_t(n * e));
  t.dg.resize(size_t(n * f));
  t.dh.resize(size_t(n * e));
  t.h.resize(size_t(n * e));
  float *d2 = t.d2.data(), *dg = t.dg.data(), *dh = t.dh.data(), *h = t.h.data();
  // LN2: d2 = d(h + ff) for each row.
  for (int64_t i = 0; i < n; ++i)
    layer_norm_backward_row(dyc + i * e, xhat2 + i * e, p.g2, rstd[2 * i + 1], e, d2 + i * e, gr.g2.data(),
                            gr.be2.data());
  // The feed-forward's output layer: db2, dW2 = d2^T GELU(a1), dg = d2 W2.
  add_column_sums(gr.b2.data(), d2, n, e);
  add_transposed_product(gr.w2.data(), d2, e, g, f, n, t.product, p.bf16, t.packed);
  p.w2_op.multiply(n, d2, e, dg, f);
  // GELU: da1 = dg GELU'(a1), in dg's memory.
  for (int64_t i = 0; i < n * f; ++i) dg[i] *= dgelu[i];
  // The feed-forward's input layer: db1, dW1 = da1^T h, dh = d2 + da1 W1.
  add_column_sums(gr.b1.data(), dg, n, f);
  for (int64_t i = 0; i < n; ++i)
    for (int64_t j = 0; j < e; ++j) h[i * e + j] = xhat1[i * e + j] * p.g1[j] + p.be1[j];
  add_transposed_product(gr.w1.data(), dg, f, h, e, n, t.product, p.bf16, t.packed);
  p.w1_op.multiply(n, dg, f, dh, e);
  add_into(dh, d2, n * e);
  // LN1: d1 = d(x + heads Wo^T + bo), into d2's memory; the residual's share into dx.
  float* d1 = d2;
  for (int64_t i = 0; i < n; ++i) {
    layer_norm_backward_row(dh + i * e, xhat1 + i * e, p.g1, rstd[2 * i], e, d1 + i * e, gr.g1.data(), gr.be1.data());
    add_into(dx + s.residual_row(lo + i) * e, d1 + i * e, e);
  }
  // The output projection: dbo, dWo = d1^T heads, dheads = d1 Wo.
  add_column_sums(gr.bo.data(), d1, n, e);
  add_transposed_product(gr.wo.data(), d1, e, heads + lo * e, e, n, t.product, p.bf16, t.packed);
  p.wo_op.multiply(n, d1, e, dheads + lo * e, e);
}

// The two passes in each instruction form: the bodies above compiled for AVX-512 (their row loops
// and sums in 16-lane vectors) and for the baseline; the products and GELU dispatch on their own.
#ifdef ABLENERF_HAVE_AVX2_FORM
ABLENERF_TARGET_AVX512 void forward_chunk_avx512(const TailShape& s, const TailParams& p, double eps, const float* x,
                                                 const float* heads, TailSaved& sv, bool chunk_saved, float* y,
                                                 int64_t lo, int64_t hi, std::vector<float>& h_buf,
                                                 std::vector<float>& a_buf) {
  forward_chunk_body(s, p, eps, x, heads, sv, chunk_saved, y, lo, hi, h_buf, a_buf);
}
ABLENERF_TARGET_AVX512 void backward_chunk_avx512(const TailShape& s, const TailParams& p, const float* heads,
                                                  const TailSaved& sv, const float* dy, float* dx, float* dheads,
                                                  TailGrads& gr, int64_t lo, int64_t hi, BackwardScratch& t) {
  backward_chunk_body(s, p, heads, sv, dy, dx, dheads, gr, lo, hi, t);
}
#endif

void forward_chunk(CpuVectorForm form, const TailShape& s, const TailParams& p, double eps, const float* x,
                   const float* heads, TailSaved& sv, bool chunk_saved, float* y, int64_t lo, int64_t hi,
                   std::vector<float>& h_buf, std::vector<float>& a_buf) {
#ifdef ABLENERF_HAVE_AVX2_FORM
  if (form == CpuVectorForm::Avx512)
    return forward_chunk_avx512(s, p, eps, x, heads, sv, chunk_saved, y, lo, hi, h_buf, a_buf);
#endif
  forward_chunk_body(s, p, eps, x, heads, sv, chunk_saved, y, lo, hi, h_buf, a_buf);
}

void backward_chunk(CpuVectorForm form, const TailShape& s, const TailParams& p, const float* heads,
                    const TailSaved& sv, const float* dy, float* dx, float* dheads, TailGrads& gr, int64_t lo,
                    int64_t hi, BackwardScratch& t) {
#ifdef ABLENERF_HAVE_AVX2_FORM
  if (form == CpuVectorForm::Avx512) return backward_chunk_avx512(s, p, heads, sv, dy, dx, dheads, gr, lo, hi, t);
#endif
  backward_chunk_body(s, p, heads, sv, dy, dx, dheads, gr, lo, hi, t);
}

torch::Tensor from_vector(const std::vector<float>& v, const torch::Tensor& like) {
  auto t = torch::empty(like.sizes(), like.options());
  std::copy(v.begin(), v.end(), t.data_ptr<float>());
  return t;
}

TailShape shape_of(const torch::Tensor& x, const torch::Tensor& heads, const BlockTailWeights& w) {
  return {heads.size(0) * heads.size(1), x.size(0) * x.size(1), heads.size(1), heads.size(2), w.ff_in_weight.size(0)};
}

// One call's forward over every chunk; with `keep` the saved values are full-size (for backward).
torch::Tensor forward_all(const torch::Tensor& x, const torch::Tensor& heads, const BlockTailWeights& w, double eps,
                          int64_t chunk, CpuVectorForm form, bool bf16, bool keep, TailSaved* saved) {
  const TailShape s = shape_of(x, heads, w);
  const TailParams p(w, s, TailPass::Forward, bf16);
  const int64_t held = keep ? s.rows : std::min(chunk, s.rows);
  const auto opts = heads.options();
  TailSaved sv{torch::empty({held, s.e}, opts), torch::empty({held, s.f}, opts), torch::empty({held, s.f}, opts),
               torch::empty({held, s.e}, opts), torch::empty({held, 2}, opts)};
  auto y = torch::empty(heads.sizes(), opts);
  std::vector<float> h_buf, a_buf;
  for (int64_t lo = 0; lo < s.rows; lo += chunk)
    forward_chunk(form, s, p, eps, x.data_ptr<float>(), heads.data_ptr<float>(), sv, !keep, y.data_ptr<float>(), lo,
                  std::min(s.rows, lo + chunk), h_buf, a_buf);
  if (saved) *saved = sv;
  return y;
}

// Inputs in the order of BlockTailFunction::forward's weights.
BlockTailWeights weights_from(const torch::autograd::variable_list& v, size_t first) {
  return {v[first],     v[first + 1], v[first + 2], v[first + 3], v[first + 4],
          v[first + 5], v[first + 6], v[first + 7], v[first + 8], v[first + 9]};
}

class BlockTailFunction : public torch::autograd::Function<BlockTailFunction> {
 public:
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& x,
                               const torch::Tensor& heads, const torch::Tensor& wo, const torch::Tensor& bo,
                               const torch::Tensor& g1, const torch::Tensor& be1, const torch::Tensor& w1,
                               const torch::Tensor& b1, const torch::Tensor& w2, const torch::Tensor& b2,
                               const torch::Tensor& g2, const torch::Tensor& be2, double eps, int64_t chunk,
                               int64_t form) {
    const BlockTailWeights w{wo, bo, g1, be1, w1, b1, w2, b2, g2, be2};
    TailSaved sv;
    // The products' precision is the calling thread's now; the backward may run on another.
    const bool bf16 = token_products_bf16();
    auto y = forward_all(x, heads, w, eps, chunk, CpuVectorForm(form), bf16, /*keep=*/true, &sv);
    ctx->save_for_backward(
        {x, heads, wo, bo, g1, be1, w1, b1, w2, b2, g2, be2, sv.xhat1, sv.g, sv.dgelu, sv.xhat2, sv.rstd});
    ctx->saved_data["chunk"] = chunk;
    ctx->saved_data["form"] = form;
    ctx->saved_data["bf16"] = bf16;
    return y;
  }

  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                 torch::autograd::variable_list grads) {
    const auto v = ctx->get_saved_variables();
    const auto &x = v[0], &heads = v[1];
    const BlockTailWeights w = weights_from(v, 2);
    const TailSaved sv{v[12], v[13], v[14], v[15], v[16]};
    const int64_t chunk = ctx->saved_data["chunk"].toInt();
    const auto form = CpuVectorForm(ctx->saved_data["form"].toInt());
    const TailShape s = shape_of(x, heads, w);
    const TailParams p(w, s, TailPass::Backward, ctx->saved_data["bf16"].toBool());
    const auto dy = grads[0].contiguous();
    auto dx = torch::zeros(x.sizes(), x.options());
    auto dheads = torch::empty(heads.sizes(), heads.options());
    TailGrads gr(s);
    BackwardScratch scratch;
    for (int64_t lo = 0; lo < s.rows; lo += chunk)
      backward_chunk(form, s, p, heads.data_ptr<float>(), sv, dy.data_ptr<float>(), dx.data_ptr<float>(),
                     dheads.data_ptr<float>(), gr, lo, std::min(s.rows, lo + chunk), scratch);
    return {dx,
            dheads,
            from_vector(gr.wo, w.out_weight),
            from_vector(gr.bo, w.out_bias),
            from_vector(gr.g1, w.norm1_weight),
            from_vector(gr.be1, w.norm1_bias),
            from_vector(gr.w1, w.ff_in_weight),
            from_vector(gr.b1, w.ff_in_bias),
            from_vector(gr.w2, w.ff_out_weight),
            from_vector(gr.b2, w.ff_out_bias),
            from_vector(gr.g2, w.norm2_weight),
            from_vector(gr.be2, w.norm2_bias),
            torch::Tensor(),
            torch::Tensor(),
            torch::Tensor()};
  }
};

void check_vector(const char* name, const torch::Tensor& t, int64_t size) {
  TORCH_CHECK(t.defined(), kBlockTailOp, ": ", name, " is undefined");
  TORCH_CHECK(t.dim() == 1 && t.size(0) == size, kBlockTailOp, ": ", name, " must have shape (", size, "), got ",
              t.sizes());
}

void check_matrix(const char* name, const torch::Tensor& t, int64_t rows, int64_t cols) {
  TORCH_CHECK(t.defined(), kBlockTailOp, ": ", name, " is undefined");
  TORCH_CHECK(t.dim() == 2 && t.size(0) == rows && t.size(1) == cols, kBlockTailOp, ": ", name, " must have shape (",
              rows, ", ", cols, "), got ", t.sizes());
}

void check_inputs(const torch::Tensor& x, const torch::Tensor& heads, const BlockTailWeights& w, double eps,
                  int64_t chunk_rows) {
  TORCH_CHECK(heads.defined() && heads.dim() == 3 && heads.numel() > 0, kBlockTailOp,
              ": heads must be a non-empty (B, L, E) tensor, got ",
              heads.defined() ? heads.sizes() : at::IntArrayRef{});
  const int64_t b = heads.size(0), l = heads.size(1), e = heads.size(2);
  TORCH_CHECK(x.defined() && x.dim() == 3 && (x.size(0) == b || x.size(0) == 1) && x.size(1) == l && x.size(2) == e,
              kBlockTailOp, ": x must have shape (", b, " or 1, ", l, ", ", e, ") like heads, got ",
              x.defined() ? x.sizes() : at::IntArrayRef{});
  TORCH_CHECK(w.ff_in_weight.defined() && w.ff_in_weight.dim() == 2 && w.ff_in_weight.size(0) > 0, kBlockTailOp,
              ": ff_in_weight must be a non-empty (F, E) matrix");
  const int64_t f = w.ff_in_weight.size(0);
  check_matrix("out_weight", w.out_weight, e, e);
  check_vector("out_bias", w.out_bias, e);
  check_vector("norm1_weight", w.norm1_weight, e);
  check_vector("norm1_bias", w.norm1_bias, e);
  check_matrix("ff_in_weight", w.ff_in_weight, f, e);
  check_vector("ff_in_bias", w.ff_in_bias, f);
  check_matrix("ff_out_weight", w.ff_out_weight, e, f);
  check_vector("ff_out_bias", w.ff_out_bias, e);
  check_vector("norm2_weight", w.norm2_weight, e);
  check_vector("norm2_bias", w.norm2_bias, e);
  TORCH_CHECK(block_tail_available(x, heads, w), kBlockTailOp, ": every tensor must be a CPU float32 tensor");
  TORCH_CHECK(eps >= 0, kBlockTailOp, ": eps must be >= 0, got ", eps);
  TORCH_CHECK(chunk_rows >= 0, kBlockTailOp, ": chunk_rows must be >= 0, got ", chunk_rows);
}

}  // namespace block_tail_impl

namespace tail = block_tail_impl;

bool block_tail_available(const torch::Tensor& x, const torch::Tensor& heads, const BlockTailWeights& w) {
  for (const auto* t : {&x, &heads, &w.out_weight, &w.out_bias, &w.norm1_weight, &w.norm1_bias, &w.ff_in_weight,
                        &w.ff_in_bias, &w.ff_out_weight, &w.ff_out_bias, &w.norm2_weight, &w.norm2_bias})
    if (!t->defined() || !t->device().is_cpu() || t->scalar_type() != torch::kFloat) return false;
  return true;
}

torch::Tensor block_tail(const torch::Tensor& x, const torch::Tensor& heads, const BlockTailWeights& w, double eps,
                         int64_t chunk_rows, CpuVectorForm form) {
  RECORD_FUNCTION("ablenerf::block_tail", std::vector<c10::IValue>());
  tail::check_inputs(x, heads, w, eps, chunk_rows);
  TORCH_CHECK(cpu_vector_form_available(form), tail::kBlockTailOp, ": this CPU does not run the requested form");
  const int64_t chunk = chunk_rows > 0 ? chunk_rows : tail::default_chunk_rows(heads.size(2), w.ff_in_weight.size(0));
  const auto c = [](const torch::Tensor& t) { return t.contiguous(); };
  const BlockTailWeights wc{c(w.out_weight),   c(w.out_bias),   c(w.norm1_weight),  c(w.norm1_bias),
                            c(w.ff_in_weight), c(w.ff_in_bias), c(w.ff_out_weight), c(w.ff_out_bias),
                            c(w.norm2_weight), c(w.norm2_bias)};
  const auto xc = c(x), hc = c(heads);
  bool needs_graph = false;
  if (torch::GradMode::is_enabled())
    for (const auto* t : {&xc, &hc, &wc.out_weight, &wc.out_bias, &wc.norm1_weight, &wc.norm1_bias, &wc.ff_in_weight,
                          &wc.ff_in_bias, &wc.ff_out_weight, &wc.ff_out_bias, &wc.norm2_weight, &wc.norm2_bias})
      needs_graph = needs_graph || t->requires_grad();
  if (!needs_graph) {
    return tail::forward_all(xc, hc, wc, eps, chunk, form, token_products_bf16(), /*keep=*/false, nullptr);
  }
  return tail::BlockTailFunction::apply(xc, hc, wc.out_weight, wc.out_bias, wc.norm1_weight, wc.norm1_bias,
                                        wc.ff_in_weight, wc.ff_in_bias, wc.ff_out_weight, wc.ff_out_bias,
                                        wc.norm2_weight, wc.norm2_bias, eps, chunk, static_cast<int64_t>(form));
}

torch::Tensor block_tail_reference(const torch::Tensor& x, const torch::Tensor& heads, const BlockTailWeights& w,
                                   double eps) {
  const int64_t e = heads.size(-1);
  const auto h =
      at::layer_norm(x + torch::linear(heads, w.out_weight, w.out_bias), {e}, w.norm1_weight, w.norm1_bias, eps);
  const auto ff =
      torch::linear(torch::gelu(torch::linear(h, w.ff_in_weight, w.ff_in_bias)), w.ff_out_weight, w.ff_out_bias);
  return at::layer_norm(h + ff, {e}, w.norm2_weight, w.norm2_bias, eps);
}

}  // namespace ablenerf
