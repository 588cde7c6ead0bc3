#pragma once
// One image decoder for PNG and JPEG, picked by the file's magic bytes (not its extension), without
// LibTorch (fuzzed). PNG goes through png_codec.h; JPEG through libjpeg-turbo (Debian's
// libjpeg-dev), strict: truncated or corrupt files (libjpeg's warnings included) and CMYK/YCCK
// colour are refused with an InputError naming the file.
#include <string>
#include <utility>

#include "util/png_codec.h"

namespace ablenerf {

struct DecodedImage {
  PngImage image;            // 8-bit, channels 1 (grey), 3 or 4, the stored (raw) pixel grid
  int exif_orientation = 1;  // JPEG EXIF orientation 1..8 (1 when absent or unreadable)
};

DecodedImage decode_image_file(const std::string& path);

// {height, width} of the stored pixels, from the header only.
std::pair<int, int> image_size(const std::string& path);

// JPEG only (for tests and the fuzzer): decodes a JPEG file; `origin` names it in errors.
DecodedImage decode_jpeg_bytes(const std::string& bytes, const std::string& origin);
// The EXIF orientation tag of a JPEG's APP1 segment payload ("Exif\0\0" + TIFF), 1 when absent or
// malformed. Every offset is bounds-checked.
int exif_orientation(const std::string& app1);

}  // namespace ablenerf
