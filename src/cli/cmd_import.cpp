// `ablenerf import`: placeholder until its issue lands.
#include <iostream>

#include "cli/command.h"
#include "util/errors.h"

namespace ablenerf::cli {
namespace {
void setup(CLI::App& app) {
  app.allow_extras();
  app.callback([] { throw InputError("import", "", "not yet implemented"); });
}
}  // namespace
ABLENERF_COMMAND("import", 65, "Import weights of the authors' release into a run", setup);
}  // namespace ablenerf::cli
