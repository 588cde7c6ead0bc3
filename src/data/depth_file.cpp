#include "data/depth_file.h"

#include <vector>

#include "util/errors.h"
#include "util/fs.h"
#include "util/image_io.h"

namespace ablenerf {

torch::Tensor blender_depth_to_z(const torch::Tensor& png, const Intrinsics& k) {
  TORCH_CHECK(png.dim() == 3 && png.scalar_type() == torch::kUInt8, "blender_depth_to_z: expected uint8 (H, W, C)");
  const int64_t h = png.size(0), w = png.size(1);
  const auto v = png.select(2, 0).to(torch::kDouble);
  const auto dist = (1.0 - v / 255.0) * kBlenderDepthRange;
  // |(x, y, -1)| of each pixel centre's direction (data/rays.h casts the same directions).
  const auto xs = (torch::arange(w, torch::kDouble) + 0.5 - k.cx) / k.fx;
  const auto ys = (torch::arange(h, torch::kDouble) + 0.5 - k.cy) / k.fy;
  const auto len = (ys.square().unsqueeze(1) + xs.square().unsqueeze(0) + 1.0).sqrt();
  return torch::where(v > 0, dist / len, torch::zeros_like(dist)).to(torch::kFloat);
}

torch::Tensor read_frame_depth(const CaptureFrame& fr) {
  if (fr.depth_format == DepthFormat::BlenderPng) return blender_depth_to_z(read_png(fr.depth), fr.camera);
  try {
    const std::string bytes = read_file(fr.depth);
    return torch::pickle_load(std::vector<char>(bytes.begin(), bytes.end())).toTensor().to(torch::kFloat);
  } catch (const InputError&) {
    throw;
  } catch (const std::exception&) {
    throw InputError(fr.depth, fr.field, "cannot read depth tensor");
  }
}

}  // namespace ablenerf
