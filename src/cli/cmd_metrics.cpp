// `ablenerf metrics`: placeholder until its issue lands.
#include <iostream>

#include "cli/command.h"
#include "util/errors.h"

namespace ablenerf::cli {
namespace {
void setup(CLI::App& app) {
  app.allow_extras();
  app.callback([] { throw InputError("metrics", "", "not yet implemented"); });
}
}  // namespace
ABLENERF_COMMAND("metrics", 80, "PSNR, SSIM and LPIPS of one image pair", setup);
}  // namespace ablenerf::cli
