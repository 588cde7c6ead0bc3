// `ablenerf export`: writes every model parameter as a torch.load-able name -> tensor
// dictionary (save_weights format, names in docs/weights.md), either from a run folder
// (RUN/config.toml + RUN/weights.pt) or freshly initialised from a config.
#include <torch/torch.h>

#include <iostream>
#include <nlohmann/json.hpp>

#include "cli/command.h"
#include "cli/common.h"
#include "model/able_nerf.h"

namespace ablenerf::cli {
namespace cmd_export {

constexpr int64_t kDefaultSeed = 4;  // the release's seed

struct ExportArgs {
  std::string run, out;
  int64_t seed = kDefaultSeed;
  ConfigOptions cfg;
};

void run_export(const ExportArgs& a) {
  if (a.run.empty() == a.cfg.config_path.empty())
    throw InputError("export", "--run", "give exactly one of --run RUN or --config FILE");
  if (!a.run.empty() && !a.cfg.sets.empty())
    throw InputError("export", "--set", "--set applies to --config only (a run's config is fixed)");
  Config c;
  if (!a.run.empty()) {
    c = Config::load(a.run + "/config.toml");
    c.validate();
  } else {
    c = resolve_config(a.cfg);
  }
  torch::manual_seed(static_cast<uint64_t>(a.seed));
  AbleNerf model(c.model);
  if (!a.run.empty()) load_weights(model, a.run + "/weights.pt");
  save_weights(model, a.out);
  nlohmann::json j;
  j["out"] = a.out;
  j["parameters"] = model->parameter_count();
  j["source"] = a.run.empty() ? "init(seed=" + std::to_string(a.seed) + ")" : a.run;
  std::cout << j.dump() << std::endl;
}

void setup(CLI::App& app) {
  auto a = std::make_shared<ExportArgs>();
  app.add_option("--run", a->run, "Run folder holding config.toml and weights.pt");
  a->cfg.add_to(app, false);
  app.add_option("--seed", a->seed, "Initialisation seed with --config (default 4)");
  app.add_option("--out", a->out, "Output .pt file")->required();
  app.callback([a] { run_export(*a); });
}

}  // namespace cmd_export
ABLENERF_COMMAND("export", 60, "Export model weights as a torch.load-able dictionary", cmd_export::setup);
}  // namespace ablenerf::cli
