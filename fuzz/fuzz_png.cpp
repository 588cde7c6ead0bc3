// libFuzzer target: the PNG reader on arbitrary bytes. read_png and png_size must either decode
// or throw InputError; any other exception, crash or sanitizer report is a finding.
#include <cstdint>
#include <cstdio>
#include <cstdlib>

#include "fuzz_common.h"
#include "util/errors.h"
#include "util/image_io.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = ablenerf::fuzz::scratch_dir() + "/input.png";
  ablenerf::fuzz::write_bytes(path, data, size);
  try {
    const auto hw = ablenerf::png_size(path);
    const torch::Tensor im = ablenerf::read_png(path);
    // A decoded image must agree with its own header.
    if (im.size(0) != hw.first || im.size(1) != hw.second) {
      std::fprintf(stderr, "png_size and read_png disagree\n");
      std::abort();
    }
  } catch (const ablenerf::InputError&) {
    // Refused with a message: the expected outcome for bad bytes.
  }
  return 0;
}
