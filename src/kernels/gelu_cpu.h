#pragma once
// The exact GELU and its derivative over float arrays, in one pass (CPU):
//   GELU(a)  = a Phi(a),            Phi(a) = (1 + erf(a / sqrt 2)) / 2
//   GELU'(a) = Phi(a) + a phi(a),   phi(a) = exp(-a^2 / 2) / sqrt(2 pi)
// A fused layer's forward computes both and keeps the derivative, so its backward multiplies
// instead of evaluating erf again. The vector forms (16 lanes with AVX-512, 8 with AVX2 + FMA, chosen
// at run time by what the CPU runs) take exp from Sleef (its 1-ulp vector function) and Phi from
// that same exponential by a rational approximation of erfc (absolute error under 1.5e-7, see
// gelu_cpu.cpp); the C library's erf and exp where neither runs or Sleef was not found at build time.
#include <cstdint>

namespace ablenerf {

enum class GeluPath { Auto, Avx512, Avx2, Scalar };

// The path Auto takes on this CPU and build.
GeluPath gelu_cpu_best_path();
// True when `path` can run here (Scalar and Auto always).
bool gelu_cpu_path_available(GeluPath path);
const char* gelu_cpu_path_name(GeluPath path);

// g[i] = GELU(a[i]), d[i] = GELU'(a[i]) for i < n. `path` forces a vector form (tests); a path that
// cannot run here throws std::invalid_argument.
void gelu_and_derivative(const float* a, float* g, float* d, int64_t n, GeluPath path = GeluPath::Auto);

}  // namespace ablenerf
