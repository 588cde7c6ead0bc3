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


// Resolved keys plus derived facts (parameter count) as JSON.
nlohmann::json config_summary(const Config& c);

}  // namespace ablenerf::cli
