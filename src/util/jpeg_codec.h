#pragma once
// JPEG decoding through libjpeg-turbo (Debian: libjpeg62-turbo-dev), without LibTorch, so that the
// libFuzzer targets can be built from a handful of small translation units.
//
// Strict: a file libjpeg cannot read, and one it could only read with a warning (a truncated file,
// which libjpeg would otherwise pad with grey, or corrupt entropy-coded data), raises an InputError
// naming the file. libjpeg never calls exit(): its errors come back through setjmp/longjmp and all
// of its state is freed on every path.
//
// Thread safety: every call owns its libjpeg state and there are no globals, so any number of
// threads may decode (different or the same files) at once.
#include <cstddef>
#include <cstdint>
#include <string>
#include <utility>

#include "util/image8.h"  // Image8, kMaxImagePixels

namespace ablenerf {

// Decodes a baseline or progressive JPEG with any chroma subsampling. Colour (YCbCr or RGB) comes
// back as 3 channels (RGB), greyscale as 1 channel: the stored pixel grid, not rotated. When
// `exif_orientation` is given it receives the EXIF orientation 1..8 of the first APP1 "Exif"
// segment (1 when there is none or it is malformed; malformed EXIF never fails the decode).
// Throws InputError naming `path`:
//   field "colour space": CMYK/YCCK (Adobe) or other non-RGB/grey JPEGs;
//   field "": unreadable file, not a JPEG, libjpeg error ("not a readable JPEG: ..."), libjpeg
//   warning ("truncated or corrupt JPEG: ..."), more than kMaxImagePixels pixels (refused before
//   any pixel memory is allocated).
//
// `reduce` (1, 2, 4 or 8) decodes at 1/reduce of the stored size inside libjpeg (its scaled
// inverse DCT: 1/8 keeps each 8x8 block's DC term, its mean; 1/2 and 1/4 keep the lowest 4x4 and
// 2x2 coefficients), which skips most of the IDCT and colour-conversion work and never builds the
// full-size image. The result is ceil(width / reduce) x ceil(height / reduce). Any other value is
// std::invalid_argument. The pixel limit applies to the stored size, which comes back in
// `stored_size` ({height, width}) when given.
Image8 decode_jpeg_file(const std::string& path, int* exif_orientation = nullptr, int reduce = 1,
                        std::pair<int, int>* stored_size = nullptr);

// {height, width} of the stored (raw, unrotated) pixels, from the header only (jpeg_read_header:
// the entropy-coded data is not read). Refuses what the header alone shows decode_jpeg_file would
// refuse (colour space, size above kMaxImagePixels) with the same InputError.
std::pair<int, int> jpeg_size(const std::string& path);

// The EXIF orientation held by one APP1 segment's payload (what follows the marker's length
// bytes: "Exif\0\0", then a TIFF header "II" or "MM", 42, the IFD0 offset, then IFD0 with tag
// 0x0112 of type SHORT). 1 when the payload is not EXIF, has no orientation, holds a value outside
// 1..8, or any offset or count points outside the payload: every read is bounds-checked, so any
// bytes are safe. Used by decode_jpeg_file; public for tests.
int parse_exif_orientation(const uint8_t* app1, size_t size);

// Turns a stored image upright for display given its EXIF orientation, in place. The convention
// is EXIF's (TIFF 6.0 tag 0x0112): the value says how the stored rows and columns map to the
// viewer, and this function applies the transform that undoes it, i.e.
//   1  unchanged                      5  transpose (mirror about the main diagonal)
//   2  mirror horizontally            6  rotate 90 degrees clockwise
//   3  rotate 180 degrees             7  transverse (mirror about the anti-diagonal)
//   4  mirror vertically              8  rotate 90 degrees counter-clockwise
// so 6 means "the stored image must be rotated 90 degrees clockwise to display upright" (what
// most phones write for a portrait photo). For 5..8 width and height are swapped. With S the
// stored (H x W) image and D the result, D(r, c) is
//   1 S(r, c)  2 S(r, W-1-c)  3 S(H-1-r, W-1-c)  4 S(H-1-r, c)
//   5 S(c, r)  6 S(H-1-c, r)  7 S(H-1-c, W-1-r)  8 S(c, W-1-r).
// Any other value leaves the image unchanged (no error). An image whose pixel buffer does not
// hold height * width * channels bytes is a programming error: std::invalid_argument.
void apply_exif_orientation(Image8& im, int orientation);

}  // namespace ablenerf
