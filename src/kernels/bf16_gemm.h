#pragma once
// Products of float32 matrices with bfloat16 operands and float32 sums on the CPU:
//
//   C (m x n, row stride ldc) = bf16(A) bf16(B)
//   A (m x k): a[i * lda + p], float32, rounded to bfloat16 inside the kernel;
//   B (k x n): packed once per product (Bf16Operand) from any strided float32 matrix.
//
// bf16(x) rounds to the nearest bfloat16, ties to even, and flushes subnormals to signed zero (as
// AMX's instructions do). Every product of two bfloat16 numbers is exact in float32; only the
// order and rounding of the float32 sums differ between the forms:
//   Amx        Intel AMX tiles (TDPBF16PS: 16 x 32 times 32 x 16 per instruction), Xeon from
//              Sapphire Rapids on, once Linux grants the process the tiles' state; A converted 32
//              rows at a time (VCVTNE2PS2BF16), 32 x 32 blocks of C in four tiles;
//   Reference  plain loops over the rounded operands, any CPU (the tests' reference).
// Amx is chosen at run time where the CPU has it. At the capture preset's training shapes it runs
// 2.3-4.0x small_gemm's float32 products, packing included (`ablenerf bench`, token_products).
// AVX-512 BF16's VDPBF16PS alone (without tiles) measured 0.55x small_gemm on a Sapphire Rapids
// core and is not used. Without AMX the model keeps its products in float32 (model/compute.h).
//
// Used by the transformer's token products on the CPU when compute.precision = "bf16"
// (kernels/token_product.h): the linear layers' and the block tail's forward and input-gradient
// products. Weight gradients stay float32.
#include <cstdint>

#include "kernels/aligned_buffer.h"

namespace ablenerf {

enum class Bf16GemmForm { Amx, Reference };

// True when this CPU (and, for Amx, the kernel's grant of the tile state) runs `form`.
bool bf16_gemm_form_available(Bf16GemmForm form);
// Amx where available, else Reference.
Bf16GemmForm bf16_gemm_best_form();
// True when the best form is Amx (faster than float32 products).
bool cpu_has_bf16_products();
const char* bf16_gemm_form_name(Bf16GemmForm form);

// x rounded to bfloat16 (nearest, ties to even; NaN stays NaN; subnormals to signed zero), as bits
// and as the float it stands for.
uint16_t bf16_bits(float x);
float bf16_round(float x);

// B (k x n) rounded to bfloat16 in pairs of rows: element (p, j) at
// data()[((p / 2) * n_padded() + j) * 2 + p % 2], with k padded to a multiple of 32 and n to a
// multiple of 16 by zeros: the layout of an AMX tile's B operand.
class Bf16Operand {
 public:
  // Element (p, j) of B is b[p * row_stride + j * col_stride]: B = W^T of a weight W (n x k,
  // row-major) is pack(W, k, n, 1, k); B = W is pack(W, k, n, n, 1). `form`: the instructions
  // that pack (Amx: AVX-512 conversions where a stride is 1; Reference: one value at a time); the
  // same bits either way.
  void pack(const float* b, int64_t k, int64_t n, int64_t row_stride, int64_t col_stride,
            Bf16GemmForm form = bf16_gemm_best_form());
  int64_t k() const { return k_; }
  int64_t n() const { return n_; }
  int64_t k_padded() const { return k_padded_; }
  int64_t n_padded() const { return n_padded_; }
  const uint16_t* data() const { return k_ > 0 ? data_.data() : nullptr; }

 private:
  AlignedBuffer<uint16_t> data_;
  int64_t k_ = 0, n_ = 0, k_padded_ = 0, n_padded_ = 0;
};

// C = bf16(A) B for A (m x b.k()), m >= 0. Throws c10::Error naming bf16_gemm and the argument on
// a bad size or a form this CPU does not run.
void bf16_gemm(int64_t m, const float* a, int64_t lda, const Bf16Operand& b, float* c, int64_t ldc);
void bf16_gemm_in(Bf16GemmForm form, int64_t m, const float* a, int64_t lda, const Bf16Operand& b, float* c,
                  int64_t ldc);

// C (m x n) = bf16(A)^T B for A (b.k() x m, row stride lda >= m): a weight's gradient dy^T x summed
// over b.k() tokens, with B packed from x (tokens x n) as pack(x, tokens, n, ldx, 1). On AMX, A's
// columns become tile rows through 16 x 16 transposes in registers.
void bf16_gemm_at(int64_t m, const float* a, int64_t lda, const Bf16Operand& b, float* c, int64_t ldc);
void bf16_gemm_at_in(Bf16GemmForm form, int64_t m, const float* a, int64_t lda, const Bf16Operand& b, float* c,
                     int64_t ldc);

}  // namespace ablenerf
