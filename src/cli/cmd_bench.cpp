// `ablenerf bench`: placeholder until its issue lands.
#include <iostream>

#include "cli/command.h"
#include "util/errors.h"

namespace ablenerf::cli {
namespace {
void setup(CLI::App& app) {
  app.allow_extras();
  app.callback([] { throw InputError("bench", "", "not yet implemented"); });
}
}  // namespace
ABLENERF_COMMAND("bench", 50, "Measure training and rendering speed", setup);
}  // namespace ablenerf::cli
