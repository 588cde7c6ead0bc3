#pragma once
// The presets by name: the TOML files of configs/ compiled into the binary when it is built, so
// that `--preset capture` works from any folder and in an installed copy. The files stay the
// source (CMake regenerates the table when one changes); `--config FILE` still reads any file.
#include <string>
#include <vector>

namespace ablenerf::cli {

struct Preset {
  const char* name;  // the file's name without .toml: capture, capture_gpu, demo, blender, ...
  const char* toml;  // its text
};

// Every preset, in the order of their file names.
const std::vector<Preset>& presets();

// The names joined by ", " (for help and error lines).
std::string preset_names();

}  // namespace ablenerf::cli
