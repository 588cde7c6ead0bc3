#pragma once
// The dataset-loading options a run's config implies (data.downscale, data.background, near/far),
// in one place for every command that loads a dataset for a config.
#include <string>
#include <vector>

#include "data/dataset.h"
#include "util/config.h"

namespace ablenerf {

// `splits` empty = every split the dataset has.
LoadOptions load_options_for(const Config& config, std::vector<std::string> splits = {});

}  // namespace ablenerf
