#include "util/image_io.h"

#include <cstring>

#include "util/image_codec.h"
#include "util/png_codec.h"

namespace ablenerf {

torch::Tensor image_tensor(const Image8& image) {
  auto out = torch::empty({image.height, image.width, image.channels}, torch::kUInt8);
  std::memcpy(out.data_ptr<uint8_t>(), image.pixels.data(), image.pixels.size());
  return out;
}

torch::Tensor read_png(const std::string& path) { return image_tensor(decode_png_file(path)); }

torch::Tensor to_uint8(const torch::Tensor& image) {
  if (image.scalar_type() == torch::kUInt8) return image.contiguous();
  return (image.detach().to(torch::kFloat).clamp(0, 1) * 255.0f + 0.5f).floor().to(torch::kUInt8).contiguous();
}

void write_png(const std::string& path, const torch::Tensor& image) {
  torch::Tensor im = image.dim() == 2 ? image.unsqueeze(-1) : image;
  TORCH_CHECK(im.dim() == 3, "write_png expects (H,W,C)");
  const int c = static_cast<int>(im.size(2));
  TORCH_CHECK(c == 1 || c == 3 || c == 4, "write_png expects 1, 3 or 4 channels");
  const torch::Tensor bytes = to_uint8(im.cpu());
  encode_png_file(path, static_cast<int>(bytes.size(1)), static_cast<int>(bytes.size(0)), c, bytes.data_ptr<uint8_t>());
}

torch::Tensor box_downscale(const torch::Tensor& image, int factor) {
  TORCH_CHECK(factor >= 1, "downscale factor must be >= 1");
  if (factor == 1) return image;
  const int64_t h = image.size(0) / factor, w = image.size(1) / factor, c = image.size(2);
  auto cropped = image.slice(0, 0, h * factor).slice(1, 0, w * factor);
  return cropped.reshape({h, factor, w, factor, c}).mean({1, 3});
}

}  // namespace ablenerf
