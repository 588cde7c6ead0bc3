#include "eval/camera_align.h"

#include <cmath>

#include "eval/photo_fit.h"
#include "model/camera_refine.h"

namespace ablenerf {

CameraAlignment align_camera(AbleNerf& model, const torch::Tensor& c2w, const Intrinsics& cam,
                             const torch::Tensor& image, const torch::Tensor& keep, double near, double far,
                             const CameraAlignOptions& o, const torch::Device& device) {
  TORCH_CHECK(c2w.dim() == 2 && c2w.size(0) >= 3 && c2w.size(1) == 4, "align_camera: c2w must be (3,4)");
  CameraAlignment out;
  out.c2w = c2w.slice(0, 0, 3).clone();
  CameraRefine refine(1, /*lr_scale=*/1.0, /*centred=*/false);
  refine->to(device);
  const PhotoFit fit =
      fit_to_photo(model, c2w, cam, image, allowed_pixels(image.size(0), image.size(1), keep, 0, image.size(1)),
                   {refine->parameter()}, {o.steps, o.rays, o.lr, o.seed}, device,
                   [&](const Rays& rays, const torch::Tensor& camera) {
                     return model->forward(refine->forward(rays, camera), near, far);
                   });
  out.mse_before = fit.mse_before, out.mse_after = fit.mse_after;
  const auto pose = c2w.slice(0, 0, 3).unsqueeze(0).to(device);
  torch::NoGradGuard no_grad;
  out.c2w = refine->corrected(pose)[0].to(c2w.scalar_type()).cpu();
  const auto c = refine->correction()[0].to(torch::kDouble).cpu();
  out.rotation_deg = c.slice(0, 0, 3).norm().item<double>() * 180.0 / M_PI;
  out.shift = c.slice(0, 3, 6).norm().item<double>();
  return out;
}

}  // namespace ablenerf
