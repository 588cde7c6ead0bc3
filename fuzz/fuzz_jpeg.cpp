// libFuzzer target: the PNG/JPEG decoder (util/image_codec and util/jpeg_codec, torch-free) on
// arbitrary bytes, JPEG seeds first. image_size and decode_image_file must either decode or throw
// InputError; any other exception, a crash, a sanitizer report (libjpeg reading or writing out of
// bounds, the EXIF parser leaving its segment, a leak of libjpeg state on an error path) or a
// decoded image that contradicts its own header is a finding. The decoded image is also turned
// upright (apply_exif_orientation) for its own orientation and back.
//
// Images the header says hold more than kFuzzMaxPixels pixels are only measured, not decoded: an
// arithmetic-coded JPEG of a few hundred bytes may legally describe a flat 60000x4000 image (its
// decoder reads zeros past the end of the data, as the standard asks), and decoding and copying
// that four times under the sanitizers outlasts libFuzzer's per-input timeout without testing
// anything a smaller image does not. The product's own limit (kMaxImagePixels) is still fuzzed by
// image_size, which reads the same header.
#include <cstdint>
#include <cstdio>
#include <cstdlib>

#include "fuzz_common.h"
#include "util/errors.h"
#include "util/image_codec.h"
#include "util/jpeg_codec.h"

namespace {

[[noreturn]] void finding(const char* what) {
  std::fprintf(stderr, "fuzz_jpeg: %s\n", what);
  std::abort();
}

// The orientation that undoes `o`: the rotations 6 and 8 undo each other, the rest are their own
// inverse.
int inverse_orientation(int o) { return o == 6 ? 8 : o == 8 ? 6 : o; }

constexpr int64_t kFuzzMaxPixels = int64_t(1) << 22;

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = ablenerf::fuzz::scratch_dir() + "/input.jpg";
  ablenerf::fuzz::write_bytes(path, data, size);
  try {
    const auto hw = ablenerf::image_size(path);
    if (int64_t(hw.first) * hw.second > kFuzzMaxPixels) return 0;
    ablenerf::DecodedImage d = ablenerf::decode_image_file(path);
    ablenerf::Image8& im = d.image;
    // A decoded image must agree with its own header and hold exactly H * W * C bytes.
    if (im.height != hw.first || im.width != hw.second) finding("image_size and decode_image_file disagree");
    if (im.channels != 1 && im.channels != 3 && im.channels != 4) finding("channel count not in {1, 3, 4}");
    if (im.pixels.size() != static_cast<size_t>(im.width) * im.height * im.channels)
      finding("pixel buffer size is not width * height * channels");
    const int o = d.exif_orientation;
    if (o < 1 || o > 8) finding("EXIF orientation outside 1..8");
    // Upright: the same bytes, width and height swapped for 5..8; undone, the stored image again.
    const ablenerf::Image8 stored = im;
    ablenerf::apply_exif_orientation(im, o);
    const bool swapped = o >= 5;
    const int want_h = swapped ? stored.width : stored.height;
    const int want_w = swapped ? stored.height : stored.width;
    if (im.height != want_h || im.width != want_w) finding("apply_exif_orientation gave the wrong size");
    if (im.channels != stored.channels || im.pixels.size() != stored.pixels.size())
      finding("apply_exif_orientation changed the channel count or the buffer size");
    ablenerf::apply_exif_orientation(im, inverse_orientation(o));
    if (im.height != stored.height || im.width != stored.width || im.pixels != stored.pixels)
      finding("apply_exif_orientation followed by its inverse is not the identity");
  } catch (const ablenerf::InputError&) {
    // Refused with a message: the expected outcome for bad bytes.
  }
  return 0;
}
