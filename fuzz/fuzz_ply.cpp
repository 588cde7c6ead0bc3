// libFuzzer target: the PLY point reader (data/ply, torch-free) on arbitrary bytes. It must either
// return finite points or throw InputError; any other exception, a crash or a sanitizer report (an
// allocation over -rss_limit_mb included) is a finding.
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "data/ply.h"
#include "util/errors.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  try {
    const auto points = ablenerf::parse_ply_points(std::string(reinterpret_cast<const char*>(data), size), "input.ply");
    for (const auto& p : points)
      for (const double c : p)
        if (!std::isfinite(c)) {
          std::fprintf(stderr, "fuzz_ply: non-finite coordinate returned\n");
          std::abort();
        }
  } catch (const ablenerf::InputError&) {
    // Refused with a message: the expected outcome for bad bytes.
  }
  return 0;
}
