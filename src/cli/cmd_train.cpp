// `ablenerf train`: placeholder until its issue lands.
#include <iostream>

#include "cli/command.h"
#include "util/errors.h"

namespace ablenerf::cli {
namespace {
void setup(CLI::App& app) {
  app.allow_extras();
  app.callback([] { throw InputError("train", "", "not yet implemented"); });
}
}  // namespace
ABLENERF_COMMAND("train", 20, "Train a model on a dataset", setup);
}  // namespace ablenerf::cli
