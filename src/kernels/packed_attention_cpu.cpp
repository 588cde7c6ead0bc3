#include "kernels/packed_attention.h"

#include <ATen/record_function.h>
#include <dlfcn.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "kernels/cpu_parallel.h"
#include "kernels/row_reduce.h"
#include "kernels/small_gemm.h"
#include "kernels/vector_exp.h"

namespace ablenerf {

namespace {

// Below this many (ray, head) products per thread the thread start-up costs more than it saves.
constexpr int64_t kMinItemsPerThread = 16;

// CBLAS's enumerations (cblas.h).
constexpr int kCblasRowMajor = 101, kCblasNoTrans = 111, kCblasTrans = 112;

using Sgemm = void (*)(int, int, int, int, int, int, float, const float*, int, const float*, int, float, float*, int);
using Dgemm = void (*)(int, int, int, int, int, int, double, const double*, int, const double*, int, double, double*,
                       int);

// The BLAS LibTorch itself loaded (OpenBLAS here), looked up at run time: nothing extra is linked
// and builds whose BLAS exports no CBLAS (e.g. a static MKL) fall back to the reference path.
struct Cblas {
  Sgemm s = nullptr;
  Dgemm d = nullptr;
  Cblas() {
    s = reinterpret_cast<Sgemm>(dlsym(RTLD_DEFAULT, "cblas_sgemm"));
    d = reinterpret_cast<Dgemm>(dlsym(RTLD_DEFAULT, "cblas_dgemm"));
  }
};

const Cblas& cblas() {
  static const Cblas c;
  return c;
}

// Row-major C = alpha * op(A) op(B) + beta * C.
void gemm(bool ta, bool tb, int64_t m, int64_t n, int64_t k, float alpha, const float* a, int64_t lda, const float* b,
          int64_t ldb, float beta, float* c, int64_t ldc) {
  cblas().s(kCblasRowMajor, ta ? kCblasTrans : kCblasNoTrans, tb ? kCblasTrans : kCblasNoTrans, int(m), int(n), int(k),
            alpha, a, int(lda), b, int(ldb), beta, c, int(ldc));
}
void gemm(bool ta, bool tb, int64_t m, int64_t n, int64_t k, double alpha, const double* a, int64_t lda,
          const double* b, int64_t ldb, double beta, double* c, int64_t ldc) {
  cblas().d(kCblasRowMajor, ta ? kCblasTrans : kCblasNoTrans, tb ? kCblasTrans : kCblasNoTrans, int(m), int(n), int(k),
            alpha, a, int(lda), b, int(ldb), beta, c, int(ldc));
}

// One product of the attention core, C = alpha op(A) op(B): written out in registers when small
// (kernels/small_gemm.h; B^T then goes through `scratch`), BLAS otherwise.
template <class T>
void product(bool ta, bool tb, int64_t m, int64_t n, int64_t k, T alpha, const T* a, int64_t lda, const T* b,
             int64_t ldb, T* c, int64_t ldc, std::vector<T>& scratch) {
  if (!small_gemm_fits(m, n, k)) return gemm(ta, tb, m, n, k, alpha, a, lda, b, ldb, T(0), c, ldc);
  if (tb) {
    scratch.resize(static_cast<size_t>(k * n));
    transpose_into(b, n, k, ldb, scratch.data());
    b = scratch.data();
    ldb = n;
  }
  small_gemm(ta, m, n, k, alpha, a, lda, b, ldb, c, ldc);
}

// Where one operand's heads live: the (lq or lk) x dh matrix of ray b, head h starts at
// base + b * batch + h * dh, with `row` elements between consecutive tokens.
template <class T>
struct Operand {
  T* base;
  int64_t batch, row;
  T* at(int64_t b, int64_t h, int64_t dh) const { return base + b * batch + h * dh; }
};

// The layout of one call: B rays, H heads of width dh, lq queries, lk keys; and its operands.
template <class T>
struct Problem {
  int64_t b, heads, dh, lq, lk;
  Operand<const T> q, k, v;
  torch::Tensor mask;  // (lq, lk) or undefined
  double scale;
  int64_t items() const { return b * heads; }
};

// Operands of a packed tensor x (B', L, C): columns [offset, offset + E) of every token; a batch
// of one is broadcast (batch stride 0).
template <class T>
Operand<const T> operand(const torch::Tensor& x, int64_t offset) {
  return {x.data_ptr<T>() + offset, x.size(0) == 1 ? 0 : x.size(1) * x.size(2), x.size(2)};
}

// exp in place over a block: float through the vector exp (kernels/vector_exp.h), double through
// the C library's.
void exp_block(float* x, int64_t n) { exp_inplace(x, n); }
void exp_block(double* x, int64_t n) {
  for (int64_t i = 0; i < n; ++i) x[i] = std::exp(x[i]);
}

// Softmax of each of the `items` x lq rows of s (lk scores each) in place, after adding the
// additive (lq, lk) mask when given: the steps of ATen's CPU softmax (max, exp of the difference,
// sum, multiply by its reciprocal) in the probabilities' own memory (no scores scratch), the
// exponentials of the whole block in one pass. Measured at the demo preset's shape (256 x 17 x 17,
// one core): with scalar expf as fast as at::_softmax_out (~0.5 ms; exp bounds both), hence the
// vector exp for float; the backward loop below takes half the time of the four tensor ops it
// replaces (~0.06 against ~0.11 ms).
template <class T>
void softmax_rows(T* s, const T* mask, int64_t items, int64_t lq, int64_t lk) {
  const int64_t rows = items * lq;
  for (int64_t q = 0; q < rows; ++q) {
    T* row = s + q * lk;
    if (mask) {
      const T* m = mask + (q % lq) * lk;
      for (int64_t j = 0; j < lk; ++j) row[j] += m[j];
    }
    const T max = row_max(row, lk);
    for (int64_t j = 0; j < lk; ++j) row[j] -= max;
  }
  exp_block(s, rows * lk);
  for (int64_t q = 0; q < rows; ++q) {
    T* row = s + q * lk;
    const T inv = T(1) / row_sum(row, lk);
    for (int64_t j = 0; j < lk; ++j) row[j] *= inv;
  }
}

// Softmax backward of each row in place: dp <- p * (dp - sum(dp * p)) (the scale is applied by
// the products that follow).
template <class T>
void softmax_backward_rows(T* dp, const T* p, int64_t rows, int64_t lk) {
  for (int64_t r = 0; r < rows; ++r) {
    T* d = dp + r * lk;
    const T* pr = p + r * lk;
    const T dot = row_dot(d, pr, lk);
    for (int64_t j = 0; j < lk; ++j) d[j] = (d[j] - dot) * pr[j];
  }
}

// Probabilities of items [lo, hi) into p (hi - lo, lq, lk) and their weighted values into out.
template <class T>
void forward_items(const Problem<T>& pr, int64_t lo, int64_t hi, torch::Tensor p, const Operand<T>& out) {
  T* s = p.data_ptr<T>();
  const int64_t plane = pr.lq * pr.lk;
  std::vector<T> scratch;
  for (int64_t it = lo; it < hi; ++it) {
    const int64_t b = it / pr.heads, h = it % pr.heads;
    product(false, true, pr.lq, pr.lk, pr.dh, T(pr.scale), pr.q.at(b, h, pr.dh), pr.q.row, pr.k.at(b, h, pr.dh),
            pr.k.row, s + (it - lo) * plane, pr.lk, scratch);
  }
  softmax_rows(s, pr.mask.defined() ? pr.mask.template data_ptr<T>() : nullptr, hi - lo, pr.lq, pr.lk);
  const T* pp = p.data_ptr<T>();
  for (int64_t it = lo; it < hi; ++it) {
    const int64_t b = it / pr.heads, h = it % pr.heads;
    product(false, false, pr.lq, pr.dh, pr.lk, T(1), pp + (it - lo) * plane, pr.lk, pr.v.at(b, h, pr.dh), pr.v.row,
            out.at(b, h, pr.dh), out.row, scratch);
  }
}

// The forward of every item; `keep` = the (B*H, lq, lk) probabilities to save for backward, or
// undefined when nothing will be differentiated (then each thread uses a scratch of its own).
template <class T>
torch::Tensor forward_all(const Problem<T>& pr, const torch::TensorOptions& options, torch::Tensor keep) {
  auto out = torch::empty({pr.b, pr.lq, pr.heads * pr.dh}, options);
  const Operand<T> o{out.template data_ptr<T>(), pr.lq * pr.heads * pr.dh, pr.heads * pr.dh};
  const SingleThreadedBlas single;  // also when serial: OpenBLAS's pool costs more than it saves here
  parallel_slices(pr.items(), cpu_workers(pr.items(), kMinItemsPerThread), [&](int64_t, int64_t lo, int64_t hi) {
    auto p = keep.defined() ? keep.slice(0, lo, hi) : torch::empty({hi - lo, pr.lq, pr.lk}, options);
    forward_items(pr, lo, hi, p, o);
  });
  return out;
}

// Gradients of items [lo, hi): dq, dk, dv operands receive the products (every element written).
template <class T>
void backward_items(const Problem<T>& pr, int64_t lo, int64_t hi, const torch::Tensor& p_all,
                    const Operand<const T>& go, const Operand<T>& dq, const Operand<T>& dk, const Operand<T>& dv) {
  const auto p = p_all.slice(0, lo, hi);
  auto dp = torch::empty_like(p);
  const int64_t plane = pr.lq * pr.lk;
  const T* pp = p.data_ptr<T>();
  T* dpp = dp.data_ptr<T>();
  std::vector<T> scratch;
  for (int64_t it = lo; it < hi; ++it) {
    const int64_t b = it / pr.heads, h = it % pr.heads;
    // dP = dO V^T;  dV = P^T dO.
    product(false, true, pr.lq, pr.lk, pr.dh, T(1), go.at(b, h, pr.dh), go.row, pr.v.at(b, h, pr.dh), pr.v.row,
            dpp + (it - lo) * plane, pr.lk, scratch);
    product(true, false, pr.lk, pr.dh, pr.lq, T(1), pp + (it - lo) * plane, pr.lk, go.at(b, h, pr.dh), go.row,
            dv.at(b, h, pr.dh), dv.row, scratch);
  }
  // Softmax backward: dS = P * (dP - rowsum(dP * P)), in place; the scale multiplies dQ and dK below.
  softmax_backward_rows(dpp, pp, (hi - lo) * pr.lq, pr.lk);
  const T* dsp = dpp;
  for (int64_t it = lo; it < hi; ++it) {
    const int64_t b = it / pr.heads, h = it % pr.heads;
    // dQ = s dS K;  dK = s dS^T Q.
    product(false, false, pr.lq, pr.dh, pr.lk, T(pr.scale), dsp + (it - lo) * plane, pr.lk, pr.k.at(b, h, pr.dh),
            pr.k.row, dq.at(b, h, pr.dh), dq.row, scratch);
    product(true, false, pr.lk, pr.dh, pr.lq, T(pr.scale), dsp + (it - lo) * plane, pr.lk, pr.q.at(b, h, pr.dh),
            pr.q.row, dk.at(b, h, pr.dh), dk.row, scratch);
  }
}

// Columns of K and V in the tensor holding them: [Q | K | V] for self-attention, [K | V] otherwise.
struct KvColumns {
  int64_t k, v;
};
KvColumns kv_columns(bool self, int64_t width) { return self ? KvColumns{width, 2 * width} : KvColumns{0, width}; }

// q_src: (Bq, Lq, C) holding Q at columns [0, E); kv: (B, Lk, C') holding K and V (for
// self-attention kv is q_src).
template <class T>
Problem<T> make_problem(const torch::Tensor& q_src, const torch::Tensor& kv, bool self, int64_t heads, int64_t width,
                        const torch::Tensor& mask, double scale) {
  const KvColumns c = kv_columns(self, width);
  Problem<T> pr{kv.size(0),
                heads,
                width / heads,
                q_src.size(1),
                kv.size(1),
                operand<T>(q_src, 0),
                operand<T>(kv, c.k),
                operand<T>(kv, c.v),
                mask.defined() && mask.numel() > 0 ? mask : torch::Tensor(),
                scale};
  return pr;
}

// Autograd node over the packed tensors, so that the gradient lands in the packed layout directly
// (no per-head copies, no zero-filled slices summed together).
class PackedAttentionFunction : public torch::autograd::Function<PackedAttentionFunction> {
 public:
  // kv_src empty = self-attention (K and V inside q_src).
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& q_src,
                               const torch::Tensor& kv_src, const torch::Tensor& mask, int64_t heads, int64_t width,
                               double scale) {
    const bool self = kv_src.numel() == 0;
    const auto& kv = self ? q_src : kv_src;
    auto p = torch::empty({kv.size(0) * heads, q_src.size(1), kv.size(1)}, q_src.options());
    torch::Tensor out;
    AT_DISPATCH_FLOATING_TYPES(q_src.scalar_type(), "packed_attention", [&] {
      const auto pr = make_problem<scalar_t>(q_src, kv, self, heads, width, mask, scale);
      out = forward_all(pr, q_src.options(), p);
    });
    ctx->save_for_backward({q_src, kv_src, mask, p});
    ctx->saved_data["heads"] = heads;
    ctx->saved_data["width"] = width;
    ctx->saved_data["scale"] = scale;
    return out;
  }

  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                 torch::autograd::variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    const auto &q_src = saved[0], &kv_src = saved[1], &mask = saved[2], &p = saved[3];
    const int64_t heads = ctx->saved_data["heads"].toInt(), width = ctx->saved_data["width"].toInt();
    const double scale = ctx->saved_data["scale"].toDouble();
    const bool self = kv_src.numel() == 0;
    const auto& kv = self ? q_src : kv_src;
    const int64_t b = kv.size(0);
    const auto go = grads[0].contiguous();
    // Self: one (B, L, 3E) gradient. Cross: dQ per ray (summed afterwards when the queries are
    // shared by the batch) and one (B, Lk, 2E) gradient for K and V.
    auto d_kv = torch::empty({b, kv.size(1), kv.size(2)}, kv.options());
    auto d_q = self ? d_kv : torch::empty({b, q_src.size(1), width}, q_src.options());
    AT_DISPATCH_FLOATING_TYPES(q_src.scalar_type(), "packed_attention_backward", [&] {
      const auto pr = make_problem<scalar_t>(q_src, kv, self, heads, width, mask, scale);
      const Operand<const scalar_t> g{go.data_ptr<scalar_t>(), go.size(1) * go.size(2), go.size(2)};
      const auto out_operand = [](torch::Tensor& x, int64_t offset) {
        return Operand<scalar_t>{x.data_ptr<scalar_t>() + offset, x.size(1) * x.size(2), x.size(2)};
      };
      const auto dq = out_operand(d_q, 0);
      const KvColumns c = kv_columns(self, width);
      const auto dk = out_operand(d_kv, c.k), dv = out_operand(d_kv, c.v);
      const SingleThreadedBlas single;
      parallel_slices(pr.items(), cpu_workers(pr.items(), kMinItemsPerThread),
                      [&](int64_t, int64_t lo, int64_t hi) { backward_items(pr, lo, hi, p, g, dq, dk, dv); });
    });
    if (self) return {d_kv, torch::Tensor(), torch::Tensor(), torch::Tensor(), torch::Tensor(), torch::Tensor()};
    if (q_src.size(0) == 1 && b != 1) d_q = d_q.sum(0, /*keepdim=*/true);
    return {d_q, d_kv, torch::Tensor(), torch::Tensor(), torch::Tensor(), torch::Tensor()};
  }
};

torch::Tensor run(const torch::Tensor& q_src, const torch::Tensor& kv_src, const torch::Tensor& mask, int64_t heads,
                  int64_t width, double scale) {
  RECORD_FUNCTION("ablenerf::packed_attention", std::vector<c10::IValue>());
  const bool self = !kv_src.defined();
  TORCH_CHECK(width % heads == 0, "packed attention: width ", width, " is not divisible by ", heads, " heads");
  const auto q = q_src.contiguous();
  const auto kv = self ? torch::Tensor() : kv_src.contiguous();
  const auto m = mask.defined() ? mask.to(q.scalar_type()).contiguous() : torch::Tensor();
  const int64_t lk = self ? q.size(1) : kv.size(1);
  TORCH_CHECK(!m.defined() || m.numel() == 0 || (m.dim() == 2 && m.size(0) == q.size(1) && m.size(1) == lk),
              "packed attention: the mask must be (", q.size(1), ", ", lk, "), got ", m.sizes());
  const bool needs_graph = torch::GradMode::is_enabled() && (q.requires_grad() || (kv.defined() && kv.requires_grad()));
  if (needs_graph)
    return PackedAttentionFunction::apply(q, self ? torch::empty({0}, q.options()) : kv,
                                          m.defined() ? m : torch::empty({0}, q.options()), heads, width, scale);
  torch::Tensor out;
  AT_DISPATCH_FLOATING_TYPES(q.scalar_type(), "packed_attention_inference", [&] {
    const auto& kvt = self ? q : kv;
    const auto pr = make_problem<scalar_t>(q, kvt, self, heads, width, m, scale);
    out = forward_all(pr, q.options(), torch::Tensor());
  });
  return out;
}

}  // namespace

bool packed_attention_available(const torch::Tensor& x) {
  if (!x.device().is_cpu()) return false;
  if (x.scalar_type() == torch::kFloat) return cblas().s != nullptr;
  if (x.scalar_type() == torch::kDouble) return cblas().d != nullptr;
  return false;
}

torch::Tensor packed_self_attention(const torch::Tensor& qkv, int64_t heads, const torch::Tensor& mask, double scale) {
  TORCH_CHECK(qkv.dim() == 3 && qkv.size(2) % 3 == 0, "packed_self_attention: expected (B, L, 3E), got ", qkv.sizes());
  return run(qkv, torch::Tensor(), mask, heads, qkv.size(2) / 3, scale);
}

torch::Tensor packed_cross_attention(const torch::Tensor& q, const torch::Tensor& kv, int64_t heads, double scale) {
  TORCH_CHECK(
      q.dim() == 3 && kv.dim() == 3 && kv.size(2) == 2 * q.size(2) && (q.size(0) == 1 || q.size(0) == kv.size(0)),
      "packed_cross_attention: expected q (B or 1, Lq, E) and kv (B, Lk, 2E), got ", q.sizes(), " and ", kv.sizes());
  return run(q, kv, torch::Tensor(), heads, q.size(2), scale);
}

}  // namespace ablenerf
