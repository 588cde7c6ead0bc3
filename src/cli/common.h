#pragma once
// Helpers shared by the CLI commands.
#include <nlohmann/json.hpp>

#include "cli/command.h"
#include "data/dataset.h"
#include "util/config.h"
#include "util/errors.h"
#include "util/log.h"

namespace ablenerf::cli {

// An option's old spelling, kept for a release: hidden from --help, it sets the same value as
// `new_name` and prints one line naming the new spelling when used.
template <class T>
void add_old_spelling(CLI::App& app, const std::string& old_name, const std::string& new_name, T& value) {
  app.add_option(old_name, value)->group("")->each([old_name, new_name](const std::string&) {
    log_warn(old_name + " is now " + new_name + " (the old spelling still works in this release)");
  });
}

// --json on a command whose report is text: the report as one JSON object on stdout instead.
inline CLI::Option* add_json_flag(CLI::App& app, bool& json) {
  return app.add_flag("--json", json, "Print the report as one JSON object on stdout instead of text");
}
// --json on a command whose report is JSON already: accepted, so that a script may pass it to every
// command.
inline CLI::Option* add_json_flag(CLI::App& app) {
  return app.add_flag_callback(
      "--json", [] {}, "The report is one JSON object on stdout either way");
}

// Defaults <- --config file <- --set overrides, validated.
Config resolve_config(const ConfigOptions& opts);

// "cpu", "cuda", "cuda:N" or "auto" (CUDA when available). InputError naming --device for
// anything else, and for a GPU asked for where there is none (a CPU-only LibTorch, no GPU, or
// an index past the last GPU).
torch::Device parse_device(const std::string& name);

// Resolved keys plus derived facts (parameter count) as JSON.
nlohmann::json config_summary(const Config& c);

}  // namespace ablenerf::cli
