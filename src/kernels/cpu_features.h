#pragma once
// What the CPU kernels with a vector form share: the run-time check for AVX2 + FMA, the attribute
// that compiles one function for them (next to a baseline build of the same code), and forced
// inlining, so that a body written once with GCC/Clang vector extensions is compiled into both.
//
//   ABLENERF_TARGET_AVX2 void f_avx2(...) { body(...); }   // only where ABLENERF_HAVE_AVX2_FORM
//   void f_base(...) { body(...); }
//   if (cpu_has_avx2_fma()) f_avx2(...); else f_base(...);

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define ABLENERF_HAVE_AVX2_FORM 1
#define ABLENERF_TARGET_AVX2 __attribute__((target("avx2,fma")))
// The same body compiled for 512-bit vectors (AVX-512 F with its 256-bit forms).
#define ABLENERF_TARGET_AVX512 __attribute__((target("avx512f,avx512vl,avx2,fma")))
#endif

#define ABLENERF_ALWAYS_INLINE inline __attribute__((always_inline))

// GCC contracts a * b + c into one fused multiply-add (one rounding instead of two) wherever the
// target has FMA, intrinsics included. On a function whose vector form must round as the baseline
// scalar loop does (forms that agree to the bit), contraction is off.
#define ABLENERF_SEPARATE_ROUNDINGS __attribute__((optimize("fp-contract=off")))

namespace ablenerf {

// True when this CPU runs AVX2 and FMA instructions (checked once).
inline bool cpu_has_avx2_fma() {
#ifdef ABLENERF_HAVE_AVX2_FORM
  static const bool yes = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
  return yes;
#else
  return false;
#endif
}

// True when this CPU runs AVX-512 F and VL instructions (checked once); such a CPU has AVX2 and FMA.
inline bool cpu_has_avx512() {
#ifdef ABLENERF_HAVE_AVX2_FORM
  static const bool yes = cpu_has_avx2_fma() && __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl");
  return yes;
#else
  return false;
#endif
}

// The instruction forms of the CPU kernels that have a scalar loop and an AVX-512 one (Adam's
// update, the table gradient's finishing pass): Scalar runs everywhere.
enum class CpuVectorForm { Scalar, Avx512 };

inline bool cpu_vector_form_available(CpuVectorForm form) { return form == CpuVectorForm::Scalar || cpu_has_avx512(); }

inline CpuVectorForm cpu_best_vector_form() { return cpu_has_avx512() ? CpuVectorForm::Avx512 : CpuVectorForm::Scalar; }

}  // namespace ablenerf
