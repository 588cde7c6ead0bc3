// `ablenerf synth`: placeholder until its issue lands.
#include <iostream>

#include "cli/command.h"
#include "util/errors.h"

namespace ablenerf::cli {
namespace {
void setup(CLI::App& app) {
  app.allow_extras();
  app.callback([] { throw InputError("synth", "", "not yet implemented"); });
}
}  // namespace
ABLENERF_COMMAND("synth", 10, "Render the embedded demo scene (diffuse, mirror and glass objects) as a Blender dataset", setup);
}  // namespace ablenerf::cli
