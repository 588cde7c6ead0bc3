#include "eval/photo_fit.h"

#include <algorithm>

namespace ablenerf {

torch::Tensor allowed_pixels(int64_t h, int64_t w, const torch::Tensor& keep, int64_t col_begin, int64_t col_end) {
  auto allowed = torch::zeros({h, w}, torch::kBool);
  allowed.slice(1, std::clamp<int64_t>(col_begin, 0, w), std::clamp<int64_t>(col_end, 0, w)).fill_(true);
  if (keep.defined()) allowed &= keep.to(torch::kCPU, torch::kBool);
  return allowed.reshape({-1}).nonzero().squeeze(1);
}

PhotoFit fit_to_photo(AbleNerf& model, const torch::Tensor& c2w, const Intrinsics& cam, const torch::Tensor& image,
                      const torch::Tensor& allowed, const std::vector<torch::Tensor>& params, const PhotoFitOptions& o,
                      const torch::Device& device, const PhotoFitForward& forward) {
  TORCH_CHECK(c2w.dim() == 2 && c2w.size(0) >= 3 && c2w.size(1) == 4, "fit_to_photo: c2w must be (3,4)");
  TORCH_CHECK(image.dim() == 3 && image.size(2) == 3, "fit_to_photo: image must be (H,W,3)");
  PhotoFit out;
  if (allowed.numel() == 0 || o.steps <= 0 || params.empty()) return out;
  const int64_t w = image.size(1);
  torch::optim::Adam adam(params, torch::optim::AdamOptions(o.lr));
  auto gen = at::detail::createCPUGenerator(o.seed);
  const auto pose = c2w.slice(0, 0, 3).unsqueeze(0).to(device);
  const auto colours = image.reshape({-1, 3}).to(device);
  const CameraTable table = CameraTable::of({cam}, device);
  const auto zero = torch::zeros({o.rays}, torch::TensorOptions().dtype(torch::kLong).device(device));
  const CameraTable cameras = table.index(zero);
  const bool was_training = model->is_training();
  model->eval();
  for (int64_t step = 0; step < o.steps; ++step) {
    const auto pick = allowed.index_select(0, torch::randint(allowed.numel(), {o.rays}, gen, torch::kLong));
    const auto row = pick.div(w, "floor"), col = pick - row * w;
    const Rays rays = rays_for_pixels(pose.expand({o.rays, 3, 4}), col.to(device), row.to(device), cameras);
    const ModelOutput m = forward(rays, zero);
    const auto loss = (m.rgb_fine - colours.index_select(0, pick.to(device))).pow(2).mean();
    const auto grads = torch::autograd::grad({loss}, params, /*grad_outputs=*/{}, /*retain_graph=*/false,
                                             /*create_graph=*/false, /*allow_unused=*/true);
    for (size_t i = 0; i < params.size(); ++i)
      params[i].mutable_grad() = grads[i].defined() ? grads[i] : torch::zeros_like(params[i]);
    adam.step();
    const double mse = loss.item<double>();
    if (step == 0) out.mse_before = mse;
    out.mse_after = mse;
  }
  if (was_training) model->train();
  return out;
}

}  // namespace ablenerf
