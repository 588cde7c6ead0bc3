#include "eval/camera_align.h"

#include <cmath>

#include "data/rays.h"
#include "model/camera_refine.h"

namespace ablenerf {

CameraAlignment align_camera(AbleNerf& model, const torch::Tensor& c2w, const Intrinsics& cam,
                             const torch::Tensor& image, const torch::Tensor& keep, double near, double far,
                             const CameraAlignOptions& o, const torch::Device& device) {
  TORCH_CHECK(c2w.dim() == 2 && c2w.size(0) >= 3 && c2w.size(1) == 4, "align_camera: c2w must be (3,4)");
  const int64_t h = image.size(0), w = image.size(1);
  // The pixels that may be drawn (row-major indices), the photo's kept ones when it has a mask.
  const auto candidates = keep.defined() ? keep.reshape({-1}).nonzero().squeeze(1) : torch::arange(h * w);
  CameraAlignment out;
  out.c2w = c2w.slice(0, 0, 3).clone();
  if (candidates.numel() == 0 || o.steps <= 0) return out;

  CameraRefine refine(1, /*lr_scale=*/1.0, /*centred=*/false);
  refine->to(device);
  torch::optim::Adam adam(refine->parameters(), torch::optim::AdamOptions(o.lr));
  auto gen = at::detail::createCPUGenerator(o.seed);
  const auto pose = c2w.slice(0, 0, 3).unsqueeze(0).to(device);
  const auto colours = image.reshape({-1, 3}).to(device);
  const CameraTable table = CameraTable::of({cam}, device);
  const bool was_training = model->is_training();
  model->eval();
  for (int64_t step = 0; step < o.steps; ++step) {
    const auto pick = candidates.index_select(0, torch::randint(candidates.numel(), {o.rays}, gen, torch::kLong));
    const auto row = pick.div(w, "floor"), col = pick - row * w;
    const auto rows_dev = row.to(device), cols_dev = col.to(device);
    const auto zero = torch::zeros({o.rays}, torch::TensorOptions().dtype(torch::kLong).device(device));
    const Rays given = rays_for_pixels(pose.expand({o.rays, 3, 4}), cols_dev, rows_dev, table.index(zero));
    const ModelOutput m = model->forward(refine->forward(given, zero), near, far);
    const auto loss = (m.rgb_fine - colours.index_select(0, pick.to(device))).pow(2).mean();
    // Only the correction's gradient: the model's parameters are neither read for .grad nor changed.
    const auto grads = torch::autograd::grad({loss}, {refine->parameter()});
    refine->parameter().mutable_grad() = grads[0];
    adam.step();
    const double mse = loss.item<double>();
    if (step == 0) out.mse_before = mse;
    out.mse_after = mse;
  }
  if (was_training) model->train();
  torch::NoGradGuard no_grad;
  out.c2w = refine->corrected(pose)[0].to(c2w.scalar_type()).cpu();
  const auto c = refine->correction()[0].to(torch::kDouble).cpu();
  out.rotation_deg = c.slice(0, 0, 3).norm().item<double>() * 180.0 / M_PI;
  out.shift = c.slice(0, 3, 6).norm().item<double>();
  return out;
}

}  // namespace ablenerf
