#pragma once
// The [eval] section of the run configuration (util/config_section.h), registered below: how held-out views are
// rendered and scored (eval/evaluate.h, eval/metrics.h), owned by the eval module.
#include <cstdint>

#include "util/config_section.h"

namespace ablenerf {

// eval.ssim (eval/metrics.h):
enum class SsimVariant {
  // mip-NeRF / multinerf: 11x11 Gaussian (sigma 1.5), valid convolution (no padding), mean over
  // the valid map and channels; variances clamped at 0 and the covariance bounded by
  // sqrt(var_x var_y) as in multinerf. Needs images of at least 11x11.
  Standard,
  // The ABLE-NeRF authors' release: same window, zero padding of 5 ("same"-size map), mean over
  // the full map including the zero-padded borders, no clamping (biased low near borders).
  Release,
};

template <>
inline const EnumNames<SsimVariant> kEnumNames<SsimVariant>{{SsimVariant::Standard, "standard"},
                                                            {SsimVariant::Release, "release"}};

struct EvalConfig {
  static constexpr const char* kName = "eval";
  static constexpr int kOrder = 3;

  int64_t chunk = 4096;                      // rays per forward when rendering
  SsimVariant ssim = SsimVariant::Standard;  // "standard" (valid 11x11 Gaussian) | "release" (zero-padded)
  // Held-out cameras aligned against the frozen model before scoring (eval/camera_align.h): off =
  // the plain protocol; align_steps Adam steps of 512 rays per view.
  bool align_cameras = false;
  int64_t align_steps = 100;
  // NeRF-W's protocol (eval/look_fit.h): each view's look fitted on its photo's left half, scores
  // on the right half. Off = the plain protocol, the one published figures use. A run with
  // appearance codes has its code fitted first: look_code_steps Adam steps of 512 rays, step
  // look_code_lr on the code (trained codes' entries stay within a few tenths, which 100 such steps
  // reach; larger steps fit the left half's noise: docs/benchmarks/history.md, "NeRF-W's code fit").
  bool fit_look = false;
  int64_t look_code_steps = 100;
  double look_code_lr = 3e-3;

  template <class F>
  void visit(F&& f) {
    f("chunk", &chunk);
    f("ssim", &ssim);
    f("align_cameras", &align_cameras);
    f("align_steps", &align_steps);
    f("fit_look", &fit_look);
    f("look_code_steps", &look_code_steps);
    f("look_code_lr", &look_code_lr);
  }
  void validate(const SectionCheck& need) const {
    need(chunk >= 1, "chunk", "must be >= 1");
    need(align_steps >= 1, "align_steps", "must be >= 1");
    need(look_code_steps >= 1, "look_code_steps", "must be >= 1");
    need(look_code_lr > 0, "look_code_lr", "must be positive");
  }
};
ABLENERF_CONFIG_SECTION(EvalConfig);

}  // namespace ablenerf
