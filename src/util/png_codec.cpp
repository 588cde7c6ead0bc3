#include "util/png_codec.h"

#include <png.h>

#include <cstring>
#include <stdexcept>

#include "util/errors.h"
#include "util/fs.h"

namespace ablenerf {

namespace {

// Owns a png_image and frees libpng's state on every exit path (png_image_free is a no-op on an
// image that holds none).
struct PngHandle {
  png_image img;
  PngHandle() {
    std::memset(&img, 0, sizeof(img));
    img.version = PNG_IMAGE_VERSION;
  }
  ~PngHandle() { png_image_free(&img); }
  PngHandle(const PngHandle&) = delete;
  PngHandle& operator=(const PngHandle&) = delete;
};

int channels_of(png_uint_32 format) {
  const bool alpha = format & PNG_FORMAT_FLAG_ALPHA;
  const bool colour = format & PNG_FORMAT_FLAG_COLOR;
  if (colour || alpha) return alpha ? 4 : 3;  // grey+alpha is expanded to RGBA
  return 1;
}

png_uint_32 format_of(int channels) {
  return channels == 4 ? PNG_FORMAT_RGBA : channels == 3 ? PNG_FORMAT_RGB : PNG_FORMAT_GRAY;
}

void begin_read(PngHandle& p, const std::string& path) {
  if (!png_image_begin_read_from_file(&p.img, path.c_str()))
    throw InputError(path, "", std::string("not a readable PNG: ") + p.img.message);
}

}  // namespace

std::pair<int, int> png_size(const std::string& path) {
  PngHandle p;
  begin_read(p, path);
  return {static_cast<int>(p.img.height), static_cast<int>(p.img.width)};
}

Image8 decode_png_file(const std::string& path) {
  PngHandle p;
  begin_read(p, path);
  Image8 out;
  out.channels = channels_of(p.img.format);
  p.img.format = format_of(out.channels);
  const int64_t h = p.img.height, w = p.img.width;
  if (h <= 0 || w <= 0 || h * w > kMaxImagePixels)
    throw InputError(path, "", "unsupported PNG size " + std::to_string(w) + "x" + std::to_string(h));
  out.width = static_cast<int>(w);
  out.height = static_cast<int>(h);
  out.pixels.resize(static_cast<size_t>(h * w * out.channels));
  if (!png_image_finish_read(&p.img, nullptr, out.pixels.data(), 0, nullptr))
    throw InputError(path, "", std::string("corrupt or truncated PNG: ") + p.img.message);
  return out;
}

std::string encode_png(int width, int height, int channels, const uint8_t* pixels, const std::string& path) {
  if (width <= 0 || height <= 0 || (channels != 1 && channels != 3 && channels != 4))
    throw InputError(path, "", "cannot write PNG: expected a non-empty image with 1, 3 or 4 channels");
  PngHandle p;
  p.img.width = static_cast<png_uint_32>(width);
  p.img.height = static_cast<png_uint_32>(height);
  p.img.format = format_of(channels);
  // Encoded in memory (first call: the size, second: the bytes), then written atomically.
  png_alloc_size_t size = 0;
  if (!png_image_write_to_memory(&p.img, nullptr, &size, 0, pixels, 0, nullptr))
    throw std::runtime_error(path + ": cannot encode PNG: " + p.img.message);
  std::string bytes(size, '\0');
  if (!png_image_write_to_memory(&p.img, bytes.data(), &size, 0, pixels, 0, nullptr))
    throw std::runtime_error(path + ": cannot encode PNG: " + p.img.message);
  bytes.resize(size);
  return bytes;
}

void encode_png_file(const std::string& path, int width, int height, int channels, const uint8_t* pixels) {
  write_file_atomic(path, encode_png(width, height, channels, pixels, path));
}

}  // namespace ablenerf
