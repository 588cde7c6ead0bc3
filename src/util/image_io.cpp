#include "util/image_io.h"

#include <png.h>

#include <cstring>
#include <memory>

#include "util/errors.h"
#include "util/fs.h"

namespace ablenerf {

namespace {
struct PngImage {
  png_image img;
  PngImage() {
    std::memset(&img, 0, sizeof(img));
    img.version = PNG_IMAGE_VERSION;
  }
  ~PngImage() { png_image_free(&img); }
};

int channels_of(png_uint_32 format) {
  const bool alpha = format & PNG_FORMAT_FLAG_ALPHA;
  const bool colour = format & PNG_FORMAT_FLAG_COLOR;
  if (colour || alpha) return alpha ? 4 : 3;  // grey+alpha is expanded to RGBA
  return 1;
}
}  // namespace

std::pair<int, int> png_size(const std::string& path) {
  PngImage p;
  if (!png_image_begin_read_from_file(&p.img, path.c_str()))
    throw InputError(path, "", std::string("not a readable PNG: ") + p.img.message);
  return {static_cast<int>(p.img.height), static_cast<int>(p.img.width)};
}

torch::Tensor read_png(const std::string& path) {
  PngImage p;
  if (!png_image_begin_read_from_file(&p.img, path.c_str()))
    throw InputError(path, "", std::string("not a readable PNG: ") + p.img.message);
  const int c = channels_of(p.img.format);
  p.img.format = c == 4 ? PNG_FORMAT_RGBA : c == 3 ? PNG_FORMAT_RGB : PNG_FORMAT_GRAY;
  const int64_t h = p.img.height, w = p.img.width;
  if (h <= 0 || w <= 0 || h * w > (int64_t(1) << 28))
    throw InputError(path, "", "unsupported PNG size " + std::to_string(w) + "x" + std::to_string(h));
  auto out = torch::empty({h, w, c}, torch::kUInt8);
  if (!png_image_finish_read(&p.img, nullptr, out.data_ptr<uint8_t>(), 0, nullptr))
    throw InputError(path, "", std::string("corrupt or truncated PNG: ") + p.img.message);
  return out;
}

torch::Tensor to_uint8(const torch::Tensor& image) {
  if (image.scalar_type() == torch::kUInt8) return image.contiguous();
  return (image.detach().to(torch::kFloat).clamp(0, 1) * 255.0f + 0.5f).floor().to(torch::kUInt8).contiguous();
}

void write_png(const std::string& path, const torch::Tensor& image) {
  torch::Tensor im = image.dim() == 2 ? image.unsqueeze(-1) : image;
  TORCH_CHECK(im.dim() == 3, "write_png expects (H,W,C)");
  const int c = static_cast<int>(im.size(2));
  TORCH_CHECK(c == 1 || c == 3 || c == 4, "write_png expects 1, 3 or 4 channels");
  torch::Tensor bytes = to_uint8(im.cpu());
  atomic_write(path, [&](const std::string& tmp) {
    PngImage p;
    p.img.width = static_cast<png_uint_32>(bytes.size(1));
    p.img.height = static_cast<png_uint_32>(bytes.size(0));
    p.img.format = c == 4 ? PNG_FORMAT_RGBA : c == 3 ? PNG_FORMAT_RGB : PNG_FORMAT_GRAY;
    if (!png_image_write_to_file(&p.img, tmp.c_str(), 0, bytes.data_ptr<uint8_t>(), 0, nullptr))
      throw InputError(path, "", std::string("cannot write PNG: ") + p.img.message);
  });
}

torch::Tensor box_downscale(const torch::Tensor& image, int factor) {
  TORCH_CHECK(factor >= 1, "downscale factor must be >= 1");
  if (factor == 1) return image;
  const int64_t h = image.size(0) / factor, w = image.size(1) / factor, c = image.size(2);
  auto cropped = image.slice(0, 0, h * factor).slice(1, 0, w * factor);
  return cropped.reshape({h, factor, w, factor, c}).mean({1, 3});
}

}  // namespace ablenerf
