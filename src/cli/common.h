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

// "cpu", "cuda", "cuda:N" or "auto" (CUDA when available). InputError naming --device for
// anything else, and for a GPU asked for where there is none (a CPU-only LibTorch, no GPU, or
// an index past the last GPU).
torch::Device parse_device(const std::string& name);

// Resolved keys plus derived facts (parameter count) as JSON.
nlohmann::json config_summary(const Config& c);

}  // namespace ablenerf::cli
