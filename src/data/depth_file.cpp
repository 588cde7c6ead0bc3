#include "data/depth_file.h"

#include <vector>

#include "data/rays.h"
#include "util/errors.h"
#include "util/fs.h"
#include "util/image_io.h"

namespace ablenerf {

torch::Tensor blender_depth_to_z(const torch::Tensor& png, const Intrinsics& k) {
  TORCH_CHECK(png.dim() == 3 && png.scalar_type() == torch::kUInt8, "blender_depth_to_z: expected uint8 (H, W, C)");
  const auto v = png.select(2, 0).to(torch::kDouble);
  const auto dist = (1.0 - v / 255.0) * kBlenderDepthRange;
  // |(x, y, -1)| of each pixel centre's direction, as data/rays.h casts it (camera frame).
  const auto len = rays_for_image(torch::eye(4).slice(0, 0, 3), k).directions.norm(2, -1).view(v.sizes());
  return torch::where(v > 0, dist / len.to(torch::kDouble), torch::zeros_like(dist)).to(torch::kFloat);
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
