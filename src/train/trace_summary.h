#pragma once
// What a profiler trace of training steps spends per step (`ablenerf bench --trace`).
#include <cstddef>
#include <cstdint>
#include <string>

#include <nlohmann/json.hpp>

namespace ablenerf {

// What a trace spends per step: every op's self time (its duration less that of the ops nested
// in it on the same thread) summed by name, divided by `steps`. Returns {"steps", "ops_per_step",
// "self_ms_per_step", "top": [{"op", "self_ms_per_step", "calls_per_step"}, ...]} with the `top`
// ops of largest self time first. Where the trace holds the model's stages (scopes named
// "ablenerf.STAGE", model/able_nerf.cpp), "stages": [{"stage", "ms_per_step" (the scopes' whole
// durations), "calls_per_step", "ops_per_step" (the events inside them)}, ...], longest first. A CUDA trace (Kineto's:
// events of category "kernel", "gpu_memcpy" or "gpu_memset") adds "gpu": {"events_per_step", "busy_ms_per_step" (their
// summed durations), "top": [{"kernel", "ms_per_step", "share", "calls_per_step"}, ...]}; those events are left out of
// the host's self times. Throws std::invalid_argument when the trace is not such JSON.
nlohmann::json trace_summary(const std::string& trace_json, int64_t steps, size_t top);

}  // namespace ablenerf
