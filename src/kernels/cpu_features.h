#pragma once
// What the CPU kernels with a vector form share: the run-time check for AVX2 + FMA, the attribute
// that compiles one function for them (next to a baseline build of the same code), and forced
// inlining, so that a body written once with GCC/Clang vector extensions is compiled into both.
//
//   ABLENERF_TARGET_AVX2 void f_avx2(...) { body(...); }   // only where ABLENERF_HAVE_AVX2_FORM
//   void f_base(...) { body(...); }
//   if (cpu_has_avx2_fma()) f_avx2(...); else f_base(...);

#include <cstdlib>
#include <cstring>
#include <optional>

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

// The widest instructions the project's CPU kernels take: what the CPU runs, capped by the
// environment variable ABLENERF_CPU_ISA where it is set, as oneDNN's ONEDNN_MAX_CPU_ISA caps
// oneDNN's: "avx512" (no cap), "avx2" (no AVX-512 forms, no AMX tiles) or "baseline" (the scalar
// loops every x86-64 CPU runs). A machine runs the forms another CPU would take, and the tests run
// the scalar forms and the refusals of a CPU without AVX-512 or AMX on any CPU. OpenBLAS chooses
// its own kernels (OPENBLAS_CORETYPE). Read once; the program refuses any other value at its start
// (cpu_isa_cap_known).
enum class CpuIsaCap { Baseline, Avx2, Avx512 };

inline const char* cpu_isa_cap_variable() { return "ABLENERF_CPU_ISA"; }

// The cap ABLENERF_CPU_ISA names now: none (Avx512) when unset or empty; nullopt for a value not
// in the list.
inline std::optional<CpuIsaCap> cpu_isa_cap_named() {
  const char* v = std::getenv(cpu_isa_cap_variable());
  if (v == nullptr || *v == 0 || std::strcmp(v, "avx512") == 0) return CpuIsaCap::Avx512;
  if (std::strcmp(v, "avx2") == 0) return CpuIsaCap::Avx2;
  if (std::strcmp(v, "baseline") == 0) return CpuIsaCap::Baseline;
  return std::nullopt;
}

inline bool cpu_isa_cap_known() { return cpu_isa_cap_named().has_value(); }

inline CpuIsaCap cpu_isa_cap() {
  static const CpuIsaCap cap = cpu_isa_cap_named().value_or(CpuIsaCap::Avx512);
  return cap;
}

// True when this CPU runs AVX2 and FMA instructions and the cap allows them (checked once).
inline bool cpu_has_avx2_fma() {
#ifdef ABLENERF_HAVE_AVX2_FORM
  static const bool yes =
      cpu_isa_cap() != CpuIsaCap::Baseline && __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
  return yes;
#else
  return false;
#endif
}

// True when this CPU runs AVX-512 F and VL instructions and the cap allows them (checked once);
// such a CPU has AVX2 and FMA.
inline bool cpu_has_avx512() {
#ifdef ABLENERF_HAVE_AVX2_FORM
  static const bool yes = cpu_isa_cap() == CpuIsaCap::Avx512 && cpu_has_avx2_fma() &&
                          __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl");
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
