#pragma once
// PNG decoding and encoding on plain byte buffers (libpng's simplified API), without LibTorch, so
// that the libFuzzer targets can be built from a handful of small translation units.
// Strict: unreadable, truncated or corrupt files raise InputError naming the file.
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "util/image8.h"  // Image8, kMaxImagePixels

namespace ablenerf {

// Decodes an 8-bit (or 16-bit, reduced to 8) PNG. Grey stays 1 channel; grey+alpha is expanded
// to RGBA, palettes to RGB(A). Sizes above kMaxImagePixels are refused. Throws
// InputError(path, "", ...) on failure.
Image8 decode_png_file(const std::string& path);

// Reads only the header: {height, width}. Throws InputError on failure.
std::pair<int, int> png_size(const std::string& path);

// The PNG file's bytes of an 8-bit image (row-major, `channels` of 1, 3 or 4); `path` only names it
// in errors.
std::string encode_png(int width, int height, int channels, const uint8_t* pixels, const std::string& path = "image");

// Writes `pixels` (row-major height x width x channels, channels in {1, 3, 4}) as a PNG through
// write_file_atomic: an existing file is never left half-written. A bad image shape is an
// InputError naming `path`; a failed write an EnvironmentError.
void encode_png_file(const std::string& path, int width, int height, int channels, const uint8_t* pixels);

}  // namespace ablenerf
