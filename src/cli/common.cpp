#include "cli/common.h"

#include "model/able_nerf.h"

namespace ablenerf::cli {

Config resolve_config(const ConfigOptions& opts) {
  Config c = opts.config_path.empty() ? Config{} : Config::load(opts.config_path);
  for (const auto& s : opts.sets) c.set(s);
  c.validate();
  return c;
}

LoadOptions load_options(const Config& c) {
  LoadOptions o;
  o.downscale = c.data.downscale;
  o.white_background = c.data.background == "white";
  o.near = c.data.near;
  o.far = c.data.far;
  return o;
}

nlohmann::json config_summary(const Config& c) {
  nlohmann::json j;
  j["source"] = c.source;
  for (const auto& [k, v] : c.items()) j["keys"][k] = v;
  j["parameters"] = AbleNerf(c.model)->parameter_count();
  return j;
}

}  // namespace ablenerf::cli
