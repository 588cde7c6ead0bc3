#include "util/image_codec.h"

#include <algorithm>
#include <cctype>
#include <cstring>
#include <filesystem>

#include "util/errors.h"
#include "util/fs.h"
#include "util/jpeg_codec.h"
#include "util/png_codec.h"

namespace ablenerf {

namespace {

enum class ImageFormat { kPng, kJpeg };

// The format named by the file's first bytes. A JPEG starts with SOI (FF D8) followed by the
// first marker's FF; a PNG with its 8-byte signature. Read errors use read_file's messages.
ImageFormat sniff_image_format(const std::string& path) {
  const std::string bytes = read_file_prefix(path, 8);
  const auto* head = reinterpret_cast<const unsigned char*>(bytes.data());
  const size_t got = bytes.size();
  static const unsigned char kPngSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
  if (got == 8 && std::memcmp(head, kPngSignature, 8) == 0) return ImageFormat::kPng;
  if (got >= 3 && head[0] == 0xFF && head[1] == 0xD8 && head[2] == 0xFF) return ImageFormat::kJpeg;
  throw InputError(path, "", "not a PNG or JPEG image");
}

}  // namespace

DecodedImage decode_image_file(const std::string& path, int reduce) {
  DecodedImage out;
  if (sniff_image_format(path) == ImageFormat::kPng) {
    out.image = decode_png_file(path);
    out.stored_height = out.image.height;
    out.stored_width = out.image.width;
    return out;
  }
  // One pass over the header: the stored size comes back from the decode itself.
  std::pair<int, int> stored;
  out.reduced = reduce > 1 ? reduce : 1;
  out.image = decode_jpeg_file(path, &out.exif_orientation, out.reduced, &stored);
  out.stored_height = stored.first;
  out.stored_width = stored.second;
  return out;
}

std::pair<int, int> image_size(const std::string& path) {
  return sniff_image_format(path) == ImageFormat::kPng ? png_size(path) : jpeg_size(path);
}

std::vector<std::string> image_files(const std::string& dir, std::vector<std::string>* others) {
  static const std::vector<std::string> kOther{".heic", ".heif", ".tif", ".tiff", ".webp", ".bmp", ".dng",
                                               ".cr2",  ".cr3",  ".nef", ".arw",  ".raf",  ".orf", ".rw2"};
  std::vector<std::string> out;
  for (const auto& e : std::filesystem::directory_iterator(dir)) {
    if (!e.is_regular_file()) continue;
    std::string ext = e.path().extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    if (ext == ".jpg" || ext == ".jpeg" || ext == ".png")
      out.push_back(e.path().string());
    else if (others && std::find(kOther.begin(), kOther.end(), ext) != kOther.end())
      others->push_back(e.path().filename().string());
  }
  std::sort(out.begin(), out.end());
  if (others) std::sort(others->begin(), others->end());
  return out;
}

}  // namespace ablenerf
