#pragma once
// The [compute] section of the run configuration (util/config_section.h), registered below: how the model's
// arithmetic runs (model/compute.h); never changes what is computed beyond rounding.
#include "util/config_section.h"

namespace ablenerf {

enum class AttentionKernel { Fused, Plain };
enum class Precision { Fp32, Bf16, Auto };
enum class CpuSplit { Rays, Ops };

template <>
inline const EnumNames<AttentionKernel> kEnumNames<AttentionKernel>{{AttentionKernel::Fused, "fused"},
                                                                    {AttentionKernel::Plain, "plain"}};
template <>
inline const EnumNames<Precision> kEnumNames<Precision>{
    {Precision::Fp32, "fp32"}, {Precision::Bf16, "bf16"}, {Precision::Auto, "auto"}};
template <>
inline const EnumNames<CpuSplit> kEnumNames<CpuSplit>{{CpuSplit::Rays, "rays"}, {CpuSplit::Ops, "ops"}};

struct ComputeConfig {
  static constexpr const char* kName = "compute";
  static constexpr int kOrder = 4;

  // "fp32" | "bf16" (CUDA autocast, or a CPU's AMX tiles for the token products; weights, loss,
  // optimiser in fp32) | "auto" (bf16 where it runs, else fp32: model/compute.h)
  Precision precision = Precision::Fp32;
  // "fused" (CPU: packed BLAS kernel and the fused block tail; CUDA: the project's ray-attention kernel where it
  // applies, else SDPA) | "plain" (explicit softmax)
  AttentionKernel attention = AttentionKernel::Fused;
  // CPU threads: "rays" = each thread runs a slice of the rays through the whole model with
  // single-threaded BLAS; "ops" = one ray batch, threads only inside the libraries' ops.
  CpuSplit cpu_split = CpuSplit::Rays;

  template <class F>
  void visit(F&& f) {
    f("precision", &precision);
    f("attention", &attention);
    f("cpu_split", &cpu_split);
  }
  void validate(const SectionCheck&) const {}  // every value of its enums is valid
};
ABLENERF_CONFIG_SECTION(ComputeConfig);

}  // namespace ablenerf
