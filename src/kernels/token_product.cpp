#include "kernels/token_product.h"

#include <c10/util/Exception.h>

#include <stdexcept>

namespace ablenerf {

namespace {
thread_local bool bf16_products = false;
}  // namespace

bool token_products_bf16() { return bf16_products; }

TokenProductsBf16Scope::TokenProductsBf16Scope(bool on) : previous_(bf16_products) {
  if (on && !cpu_has_bf16_products())
    throw std::invalid_argument("bfloat16 token products need a CPU with AMX bfloat16 tiles");
  bf16_products = on;
}

TokenProductsBf16Scope::~TokenProductsBf16Scope() { bf16_products = previous_; }

void WeightOperand::prepare(const float* w, int64_t n, int64_t k, Use use, bool bf16) {
  TORCH_CHECK(n > 0 && k > 0, "token product: the weight must be at least 1 x 1, got ", n, " x ", k);
  bf16_ = bf16;
  const bool transposed = use == Use::Transposed;
  inner_ = transposed ? k : n;
  outer_ = transposed ? n : k;
  if (bf16) {
    // B(p, j) = W[j][p] for W^T, W[p][j] for W.
    if (transposed)
      packed_.pack(w, k, n, 1, k);
    else
      packed_.pack(w, n, k, k, 1);
    return;
  }
  if (transposed) {
    transposed_.resize(static_cast<size_t>(n * k));
    transpose_into(w, n, k, k, transposed_.data());
    b_ = transposed_.data();
  } else {
    b_ = w;
  }
}

void WeightOperand::multiply(int64_t m, const float* a, int64_t lda, float* c, int64_t ldc) const {
  TORCH_CHECK(inner_ > 0, "token product: the weight was not prepared");
  if (m == 0) return;
  if (bf16_)
    bf16_gemm(m, a, lda, packed_, c, ldc);
  else
    small_gemm(false, m, outer_, inner_, 1.0f, a, lda, b_, outer_, c, ldc);
}

}  // namespace ablenerf
