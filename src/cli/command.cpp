#include "cli/command.h"

#include "cli/presets.h"

namespace ablenerf::cli {

std::vector<CommandSpec>& command_registry() {
  static std::vector<CommandSpec> registry;
  return registry;
}

void ConfigOptions::add_to(CLI::App& app, bool config_required) {
  auto* file = app.add_option("--config", config_path, "Config file (TOML), e.g. configs/demo.toml");
  auto* named = app.add_option("--preset", preset, "A preset by name, built into the program: " + preset_names());
  file->excludes(named);
  if (config_required) {
    auto* group = app.add_option_group("config", "--config FILE or --preset NAME");
    group->add_option(file);
    group->add_option(named);
    group->require_option(1);
  }
  app.add_option("--set", sets, "Override a config key, e.g. --set model.le_count=16 (repeatable)");
}

}  // namespace ablenerf::cli
