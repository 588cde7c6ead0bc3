#include "cli/common.h"

#include "model/able_nerf.h"

namespace ablenerf::cli {

Config resolve_config(const ConfigOptions& opts) {
  Config c = opts.config_path.empty() ? Config{} : Config::load(opts.config_path);
  for (const auto& s : opts.sets) c.set(s);
  c.validate();
  return c;
}

torch::Device parse_device(const std::string& name) {
  // "cuda" means the first GPU: a device with an index (LibTorch 2.x refuses index -1 in places).
  if (name == "auto") return torch::cuda::is_available() ? torch::Device(torch::kCUDA, 0) : torch::Device(torch::kCPU);
  try {
    torch::Device d(name);
    if (d.is_cuda() && !torch::cuda::is_available())
      throw InputError("--device", name, "CUDA is not available in this build or on this machine");
    if (d.is_cuda() && !d.has_index()) d = torch::Device(torch::kCUDA, 0);
    return d;
  } catch (const c10::Error&) {
    throw InputError("--device", name, "expected cpu, cuda, cuda:N or auto");
  }
}

nlohmann::json config_summary(const Config& c) {
  nlohmann::json j;
  j["source"] = c.source;
  for (const auto& [k, v] : c.items()) j["keys"][k] = v;
  j["parameters"] = AbleNerf(c.model)->parameter_count();
  return j;
}

}  // namespace ablenerf::cli
