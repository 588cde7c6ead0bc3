#include "cli/common.h"

#include <optional>

#include "cli/presets.h"
#include "model/able_nerf.h"
#include "model/model_config.h"

namespace ablenerf::cli {

std::string preset_names() {
  std::string names;
  for (const Preset& p : presets()) names += std::string(names.empty() ? "" : ", ") + p.name;
  return names;
}

namespace {
Config preset_config(const std::string& name) {
  for (const Preset& p : presets())
    if (name == p.name) return Config::parse(p.toml, "preset " + name);
  throw InputError("--preset", name, "no such preset; the presets are " + preset_names());
}
}  // namespace

Config resolve_config(const ConfigOptions& opts) {
  Config c = !opts.preset.empty()       ? preset_config(opts.preset)
             : opts.config_path.empty() ? Config{}
                                        : Config::load(opts.config_path);
  for (const auto& s : opts.sets) c.set(s);
  c.validate();
  return c;
}

torch::Device parse_device(const std::string& name) {
  // "cuda" means the first GPU: a device with an index (LibTorch 2.x refuses index -1 in places).
  if (name == "auto") return torch::cuda::is_available() ? torch::Device(torch::kCUDA, 0) : torch::Device(torch::kCPU);
  std::optional<torch::Device> d;
  try {
    d.emplace(name);
  } catch (const c10::Error&) {
    throw InputError("--device", name, "expected cpu, cuda, cuda:N or auto");
  }
  if (!d->is_cpu() && !d->is_cuda()) throw InputError("--device", name, "expected cpu, cuda, cuda:N or auto");
  if (d->is_cuda()) {
    if (!torch::cuda::is_available())
      throw InputError("--device", name,
                       "no GPU: this LibTorch build has no CUDA or this machine has no GPU (use --device cpu)");
    const int64_t count = static_cast<int64_t>(torch::cuda::device_count());
    if (d->has_index() && d->index() >= count)
      throw InputError("--device", name,
                       "no such GPU: this machine has " + std::to_string(count) +
                           " (cuda:0 to cuda:" + std::to_string(count - 1) + ")");
    if (!d->has_index()) d.emplace(torch::kCUDA, 0);
  }
  return *d;
}

nlohmann::json config_summary(const Config& c) {
  nlohmann::json j;
  j["source"] = c.source;
  for (const auto& [k, v] : c.items()) j["keys"][k] = v;
  j["parameters"] = AbleNerf(c.get<ModelConfig>())->parameter_count();
  return j;
}

}  // namespace ablenerf::cli
