// ablenerf: the command-line entry point. Subcommands register themselves (command.h).
#include <algorithm>
#include <iostream>

#include "cli/command.h"
#include "util/errors.h"

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

int main(int argc, char** argv) {
  using namespace ablenerf;
  CLI::App app{"ablenerf: ABLE-NeRF (attention-based rendering with learnable embeddings) in C++"};
  app.set_version_flag("--version", std::string(ABLENERF_VERSION));
  app.require_subcommand(1);
  auto& reg = cli::command_registry();
  std::sort(reg.begin(), reg.end(), [](const auto& a, const auto& b) { return a.order < b.order; });
  for (auto& spec : reg) {
    CLI::App* sub = app.add_subcommand(spec.name, spec.help);
    spec.setup(*sub);
  }
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    app.exit(e);
    return kExitBadInput;
  } catch (const InputError& e) {
    std::cerr << "error: " << e.what() << std::endl;
    return kExitBadInput;
  } catch (const std::exception& e) {
    std::cerr << "internal error: " << e.what() << std::endl;
    return kExitInternal;
  }
  return kExitOk;
}
