// `ablenerf render`: placeholder until its issue lands.
#include <iostream>

#include "cli/command.h"
#include "util/errors.h"

namespace ablenerf::cli {
namespace {
void setup(CLI::App& app) {
  app.allow_extras();
  app.callback([] { throw InputError("render", "", "not yet implemented"); });
}
}  // namespace
ABLENERF_COMMAND("render", 40, "Render images or a video along a camera path", setup);
}  // namespace ablenerf::cli
