#include "train/image_size.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <optional>
#include <sstream>

#include "data/data_config.h"
#include "train/bench.h"
#include "train/train_config.h"
#include "util/errors.h"

namespace ablenerf {

std::string ImageSizeChoice::describe() const {
  std::ostringstream out;
  out << "data.downscale = " << downscale << " (auto): " << frames << " training photos at " << width << "x" << height
      << ", " << std::fixed;
  out.precision(2);
  out << pixels / 1e6 << "M pixels, drawn about ";
  out.precision(1);
  out << passes() << " times";
  if (rays_per_s > 0) {
    out.precision(0);
    out << " at " << rays_per_s << " rays/s" << (measured ? " (measured here)" : " (data.auto_rays_per_s)");
  }
  return out.str();
}

double planned_rays(const Config& cfg, double rays_per_s) {
  const TrainConfig& tc = cfg.get<TrainConfig>();
  const double by_steps = static_cast<double>(tc.steps) * static_cast<double>(tc.rays_per_step);
  if (tc.time_budget_s <= 0 || rays_per_s <= 0) return by_steps;
  return std::min(by_steps, tc.time_budget_s * rays_per_s);
}

ImageSizeChoice choose_image_size(const Capture& full, const Config& cfg, double rays_per_s,
                                  const std::function<bool(int)>& loadable) {
  const DataConfig& dc = cfg.get<DataConfig>();
  ImageSizeChoice c;
  for (const auto& split : full.splits)
    if (split.name == "train") c.frames = static_cast<int64_t>(split.frames.size());
  c.rays = planned_rays(cfg, rays_per_s);
  c.rays_per_s = cfg.get<TrainConfig>().time_budget_s > 0 ? rays_per_s : 0;
  const int short_side = std::min(full.width, full.height);
  const auto at = [&](int d) {
    c.downscale = d;
    c.width = full.width / d, c.height = full.height / d;
    c.pixels = static_cast<double>(c.frames) * c.width * c.height;
  };
  at(1);
  bool found = false;  // a loadable reduction seen
  for (const int d : kAutoDownscales) {
    // Never below the smallest short side (the finest loadable size when the photos are smaller).
    if (found && short_side / d < dc.auto_min_side) break;
    if (loadable && !loadable(d)) continue;
    at(d);
    found = true;
    if (c.pixels * dc.auto_passes <= c.rays) break;
  }
  return c;
}

ImageSizeChoice resolve_image_size(Config& cfg, const std::string& data_dir, const torch::Device& device) {
  DataConfig& dc = cfg.get<DataConfig>();
  if (dc.downscale != 0) {
    ImageSizeChoice c;
    c.downscale = dc.downscale;
    return c;
  }
  // Which reductions the capture can be read at (its metadata only; no image is decoded), and its
  // full size and photos from the first of them. With its full-size photos every reduction reads
  // (from them, or from a matching images_N/), so only a capture without them is read again per
  // size. A capture no reduction reads is read at full size, for its own error.
  std::map<int, bool> reads;
  std::optional<Capture> full;
  const auto loadable = [&](int d) {
    if (auto it = reads.find(1); it != reads.end() && it->second) return true;
    if (auto it = reads.find(d); it != reads.end()) return it->second;
    try {
      Capture at = read_capture(data_dir, {}, d);
      if (!full) full = std::move(at);
      return reads[d] = true;
    } catch (const InputError&) {
      return reads[d] = false;
    }
  };
  for (const int d : kAutoDownscales)
    if (loadable(d)) break;
  if (!full) full = read_capture(data_dir, {}, 1);
  double speed = 0;
  if (cfg.get<TrainConfig>().time_budget_s > 0)
    speed = dc.auto_rays_per_s > 0 ? dc.auto_rays_per_s : training_rays_per_s(cfg, device);
  ImageSizeChoice c = choose_image_size(*full, cfg, speed, loadable);
  c.measured = dc.auto_rays_per_s <= 0;
  dc.downscale = c.downscale;
  return c;
}

}  // namespace ablenerf
