// `ablenerf eval`: placeholder until its issue lands.
#include <iostream>

#include "cli/command.h"
#include "util/errors.h"

namespace ablenerf::cli {
namespace {
void setup(CLI::App& app) {
  app.allow_extras();
  app.callback([] { throw InputError("eval", "", "not yet implemented"); });
}
}  // namespace
ABLENERF_COMMAND("eval", 30, "Evaluate a run on a split (PSNR, SSIM, LPIPS, images, report)", setup);
}  // namespace ablenerf::cli
