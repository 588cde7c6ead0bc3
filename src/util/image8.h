#pragma once
// The decoded-image type shared by the torch-free codecs (png_codec.h, jpeg_codec.h, image_codec.h).
#include <cstdint>
#include <vector>

namespace ablenerf {

// An 8-bit decoded image: row-major (height, width, channels) bytes, channels in {1, 3, 4}, so
// pixels.size() == height * width * channels.
struct Image8 {
  int width = 0, height = 0, channels = 0;
  std::vector<uint8_t> pixels;
};

// Largest number of pixels (width * height) the decoders accept: 2^28, i.e. a 16384 x 16384
// image, 1 GiB as RGBA. Far above any NeRF dataset; refuses headers that claim absurd sizes before
// anything is allocated.
constexpr int64_t kMaxImagePixels = int64_t(1) << 28;

}  // namespace ablenerf
