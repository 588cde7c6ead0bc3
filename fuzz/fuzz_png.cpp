// libFuzzer target: the PNG decoder (util/png_codec, torch-free) on arbitrary bytes.
// decode_png_file and png_size must either decode or throw InputError; any other exception, a
// crash, a sanitizer report or a decoded image that contradicts its own header is a finding.
#include <cstdint>
#include <cstdio>
#include <cstdlib>

#include "fuzz_common.h"
#include "util/errors.h"
#include "util/png_codec.h"

namespace {

[[noreturn]] void finding(const char* what) {
  std::fprintf(stderr, "fuzz_png: %s\n", what);
  std::abort();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = ablenerf::fuzz::scratch_dir() + "/input.png";
  ablenerf::fuzz::write_bytes(path, data, size);
  try {
    const auto hw = ablenerf::png_size(path);
    const ablenerf::Image8 im = ablenerf::decode_png_file(path);
    // A decoded image must agree with its own header and hold exactly H * W * C bytes.
    if (im.height != hw.first || im.width != hw.second) finding("png_size and decode_png_file disagree");
    if (im.channels != 1 && im.channels != 3 && im.channels != 4) finding("channel count not in {1, 3, 4}");
    if (im.pixels.size() != static_cast<size_t>(im.width) * im.height * im.channels)
      finding("pixel buffer size is not width * height * channels");
  } catch (const ablenerf::InputError&) {
    // Refused with a message: the expected outcome for bad bytes.
  }
  return 0;
}
