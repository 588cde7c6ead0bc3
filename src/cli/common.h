#pragma once
// Helpers shared by the CLI commands.
#include <nlohmann/json.hpp>

#include "cli/command.h"
#include "data/dataset.h"
#include "util/config.h"
#include "util/errors.h"

namespace ablenerf::cli {

// Defaults <- --config file <- --set overrides, validated.
Config resolve_config(const ConfigOptions& opts);

// "cpu", "cuda", "cuda:N" or "auto" (CUDA when available); InputError otherwise.
torch::Device parse_device(const std::string& name);

// Dataset load options from a config.
LoadOptions load_options(const Config& c);

// Resolved keys plus derived facts (parameter count) as JSON.
nlohmann::json config_summary(const Config& c);

}  // namespace ablenerf::cli
