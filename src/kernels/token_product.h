#pragma once
// A weight as the B operand of the transformer's token products on the CPU, prepared once per call
// and then multiplied by any number of row blocks:
//
//   Use::Transposed   C (m x n) = A (m x k) W^T   a layer's forward (W: n x k, row-major)
//   Use::AsIs         C (m x k) = A (m x n) W     its input gradient
//
// in float32 (kernels/small_gemm.h over W^T copied once into an aligned scratch, or over W as it
// is) or with bfloat16 operands and float32 sums (kernels/bf16_gemm.h, W packed once).
//
// Which one a product takes is the calling thread's setting (TokenProductsBf16Scope, opened by
// model/compute.h's AutocastScope for compute.precision = "bf16" on a CPU with bfloat16 tiles);
// linear_cpu and block_tail read it in their forward and keep it for their backward, which may run
// on another thread.
#include <cstdint>

#include "kernels/bf16_gemm.h"
#include "kernels/small_gemm.h"

namespace ablenerf {

// True inside a TokenProductsBf16Scope(true) on this thread.
bool token_products_bf16();

class TokenProductsBf16Scope {
 public:
  // `on` needs a CPU with bfloat16 products (cpu_has_bf16_products); throws std::invalid_argument
  // otherwise. Scopes nest; each restores what it found.
  explicit TokenProductsBf16Scope(bool on);
  ~TokenProductsBf16Scope();
  TokenProductsBf16Scope(const TokenProductsBf16Scope&) = delete;
  TokenProductsBf16Scope& operator=(const TokenProductsBf16Scope&) = delete;

 private:
  bool previous_;
};

class WeightOperand {
 public:
  enum class Use { Transposed, AsIs };
  // W (n x k, row-major) for `use`, float32 or bfloat16. `w` must outlive the products in float32
  // as is (it is read in place).
  void prepare(const float* w, int64_t n, int64_t k, Use use, bool bf16);
  // C = A op(W): A has `inner` columns (k for Transposed, n for AsIs), C the other count.
  void multiply(int64_t m, const float* a, int64_t lda, float* c, int64_t ldc) const;
  int64_t inner() const { return inner_; }
  int64_t outer() const { return outer_; }

 private:
  bool bf16_ = false;
  int64_t inner_ = 0, outer_ = 0;
  const float* b_ = nullptr;  // float32: B (inner x outer), row-major
  AlignedFloats transposed_;
  Bf16Operand packed_;
};

}  // namespace ablenerf
