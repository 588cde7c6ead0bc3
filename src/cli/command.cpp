#include "cli/command.h"

namespace ablenerf::cli {

std::vector<CommandSpec>& command_registry() {
  static std::vector<CommandSpec> registry;
  return registry;
}

void ConfigOptions::add_to(CLI::App& app, bool config_required) {
  auto* opt = app.add_option("--config", config_path, "Config file (TOML), e.g. configs/demo.toml");
  if (config_required) opt->required();
  app.add_option("--set", sets, "Override a config key, e.g. --set model.le_count=16 (repeatable)");
}

}  // namespace ablenerf::cli
