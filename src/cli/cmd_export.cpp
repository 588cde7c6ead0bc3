// `ablenerf export`: placeholder until its issue lands.
#include <iostream>

#include "cli/command.h"
#include "util/errors.h"

namespace ablenerf::cli {
namespace {
void setup(CLI::App& app) {
  app.allow_extras();
  app.callback([] { throw InputError("export", "", "not yet implemented"); });
}
}  // namespace
ABLENERF_COMMAND("export", 60, "Export model weights as a torch.load-able dictionary", setup);
}  // namespace ablenerf::cli
