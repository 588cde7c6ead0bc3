#pragma once
// One image decoder for PNG and JPEG, picked by the file's magic bytes (not its extension), without
// LibTorch (fuzzed). PNG goes through png_codec.h (16-bit reduced to 8), JPEG through jpeg_codec.h
// (libjpeg-turbo), both strict: unreadable, truncated or corrupt files and CMYK/YCCK JPEGs are
// refused with an InputError naming the file. Safe to call from several threads at once.
#include <string>
#include <utility>
#include <vector>

// Both codecs, so that users of this header also get encode_png_file, png_size, jpeg_size and
// apply_exif_orientation.
#include "util/image8.h"
#include "util/jpeg_codec.h"
#include "util/png_codec.h"

namespace ablenerf {

struct DecodedImage {
  Image8 image;              // 8-bit, channels 1 (grey), 3 or 4, the stored (raw, unrotated) pixel grid
  int exif_orientation = 1;  // JPEG EXIF orientation 1..8 (1 for PNG, and when absent or malformed);
                             // apply_exif_orientation (jpeg_codec.h) turns the image upright
  int reduced = 1;           // `image` is the stored image reduced this many times (JPEG only)
  int stored_height = 0;     // the stored pixel grid's size, before any reduction
  int stored_width = 0;
};

// Decodes a PNG (signature 89 50 4E 47 0D 0A 1A 0A) or a JPEG (FF D8 FF). Anything else is
// InputError(path, "", "not a PNG or JPEG image"); a missing file or a folder InputError(path, "",
// "cannot read: ...").
// `reduce` asks for an image `reduce` times smaller when the codec can make one for less work than
// the full decode (JPEG: 2, 4 or 8, inside libjpeg; see decode_jpeg_file); PNG ignores it. Which
// reduction was applied comes back in `reduced`.
DecodedImage decode_image_file(const std::string& path, int reduce = 1);

// {height, width} of the stored (raw, unrotated) pixels, from the header only. Same errors.
std::pair<int, int> image_size(const std::string& path);

// The images of a folder that these decoders read, by extension (.jpg, .jpeg, .png, any case):
// regular files, full paths, sorted by name. `others`, when given, receives the names of the image
// files they do not read (HEIC, TIFF, WebP, BMP, camera RAW), sorted, so that a caller can say so.
std::vector<std::string> image_files(const std::string& dir, std::vector<std::string>* others = nullptr);

}  // namespace ablenerf
