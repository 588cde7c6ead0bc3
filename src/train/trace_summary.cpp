#include "train/trace_summary.h"

#include <algorithm>
#include <map>
#include <set>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace ablenerf {

namespace {

constexpr size_t kMaxOpName = 200;  // kernel names are whole template signatures
// The model's named stages (model/able_nerf.cpp's profiler scopes) start with this.
constexpr const char* kStagePrefix = "ablenerf.";

// Names with their summed microseconds, largest first (ties by name).
std::vector<std::pair<std::string, double>> largest_first(const std::map<std::string, double>& us) {
  std::vector<std::pair<std::string, double>> v(us.begin(), us.end());
  std::sort(v.begin(), v.end(), [](const auto& a, const auto& b) {
    return a.second != b.second ? a.second > b.second : a.first < b.first;
  });
  return v;
}

}  // namespace

nlohmann::json trace_summary(const std::string& trace_json, int64_t steps, size_t top) {
  if (steps < 1) throw std::invalid_argument("trace_summary: steps must be >= 1");
  const auto parsed = nlohmann::json::parse(trace_json, nullptr, /*allow_exceptions=*/false);
  const auto& events = parsed.is_object() && parsed.contains("traceEvents") ? parsed["traceEvents"] : parsed;
  if (!events.is_array()) throw std::invalid_argument("trace_summary: not a Chrome trace (no array of events)");
  struct Event {
    double start, end;
    std::string name;
  };
  std::map<std::string, std::vector<Event>> by_thread;
  // Kineto's device-side events (a CUDA trace): kernels, copies and fills, each timed on the GPU.
  std::map<std::string, double> device_us;
  std::map<std::string, int64_t> device_calls;
  double device_total_us = 0;
  int64_t device_events = 0;
  for (const auto& e : events) {
    if (!e.is_object() || e.value("ph", "") != "X") continue;
    if (!e.contains("ts") || !e.contains("dur") || !e["ts"].is_number() || !e["dur"].is_number())
      throw std::invalid_argument("trace_summary: an \"X\" event without numeric ts and dur");
    const std::string cat = e.contains("cat") && e["cat"].is_string() ? e["cat"].get<std::string>() : "";
    if (cat == "gpu_user_annotation") continue;  // a span over kernels listed on their own
    const double ts = e["ts"].get<double>(), dur = e["dur"].get<double>();
    if (cat == "kernel" || cat == "gpu_memcpy" || cat == "gpu_memset") {
      const std::string name = e.value("name", "?").substr(0, kMaxOpName);
      device_us[name] += dur;
      device_calls[name] += 1;
      device_total_us += dur;
      ++device_events;
      continue;
    }
    by_thread[e.contains("tid") ? e["tid"].dump() : ""].push_back({ts, ts + dur, e.value("name", "?")});
  }
  std::map<std::string, double> self_us, stage_us;
  std::map<std::string, int64_t> calls, stage_ops;
  int64_t ops = 0;
  double total_us = 0;
  for (auto& [tid, list] : by_thread) {
    // Parents first: earlier start, and the longer of two that start together.
    std::sort(list.begin(), list.end(),
              [](const Event& a, const Event& b) { return a.start != b.start ? a.start < b.start : a.end > b.end; });
    std::vector<double> child_us(list.size(), 0.0);
    std::vector<size_t> open;  // indices of the enclosing events
    for (size_t i = 0; i < list.size(); ++i) {
      while (!open.empty() && list[open.back()].end <= list[i].start) open.pop_back();
      if (!open.empty()) child_us[open.back()] += list[i].end - list[i].start;
      open.push_back(i);
    }
    for (size_t i = 0; i < list.size(); ++i) {
      if (list[i].name.rfind(kStagePrefix, 0) == 0) {
        // A stage: its whole duration, and the ops inside it (those that follow it in this order
        // and start before it ends).
        stage_us[list[i].name] += list[i].end - list[i].start;
        for (size_t j = i + 1; j < list.size() && list[j].start < list[i].end; ++j) ++stage_ops[list[i].name];
      }
      const double self = std::max(0.0, list[i].end - list[i].start - child_us[i]);
      self_us[list[i].name] += self;
      calls[list[i].name] += 1;
      total_us += self;
      ++ops;
    }
  }
  const auto ranked = largest_first(self_us);
  const double per_step = static_cast<double>(steps);
  nlohmann::json out{{"steps", steps},
                     {"ops_per_step", static_cast<double>(ops) / per_step},
                     {"self_ms_per_step", total_us / 1000.0 / per_step},
                     {"top", nlohmann::json::array()}};
  for (size_t i = 0; i < std::min(top, ranked.size()); ++i)
    out["top"].push_back({{"op", ranked[i].first},
                          {"self_ms_per_step", ranked[i].second / 1000.0 / per_step},
                          {"calls_per_step", static_cast<double>(calls[ranked[i].first]) / per_step}});
  if (!stage_us.empty()) {
    out["stages"] = nlohmann::json::array();
    for (const auto& [name, us] : largest_first(stage_us))
      out["stages"].push_back({{"stage", name},
                               {"ms_per_step", us / 1000.0 / per_step},
                               {"calls_per_step", static_cast<double>(calls[name]) / per_step},
                               {"ops_per_step", static_cast<double>(stage_ops[name]) / per_step}});
  }
  if (device_events > 0) {
    const auto by_time = largest_first(device_us);
    nlohmann::json gpu{{"events_per_step", static_cast<double>(device_events) / per_step},
                       {"busy_ms_per_step", device_total_us / 1000.0 / per_step},
                       {"top", nlohmann::json::array()}};
    for (size_t i = 0; i < std::min(top, by_time.size()); ++i)
      gpu["top"].push_back({{"kernel", by_time[i].first},
                            {"ms_per_step", by_time[i].second / 1000.0 / per_step},
                            {"share", by_time[i].second / device_total_us},
                            {"calls_per_step", static_cast<double>(device_calls[by_time[i].first]) / per_step}});
    out["gpu"] = gpu;
  }
  return out;
}

}  // namespace ablenerf
