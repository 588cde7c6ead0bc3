#include "eval/look_fit.h"

namespace ablenerf {

LookFit fit_look_left_half(const torch::Tensor& render, const torch::Tensor& photo, const torch::Tensor& keep) {
  TORCH_CHECK(render.dim() == 3 && render.size(2) == 3 && photo.sizes() == render.sizes(),
              "fit_look_left_half: render and photo must both be (H,W,3)");
  const int64_t h = render.size(0), w = render.size(1), half = w / 2;
  const auto x = render.to(torch::kCPU, torch::kDouble), y = photo.to(torch::kCPU, torch::kDouble);
  auto xl = x.slice(1, 0, half).reshape({-1, 3}), yl = y.slice(1, 0, half).reshape({-1, 3});
  if (keep.defined()) {
    const auto k = keep.to(torch::kCPU, torch::kBool).slice(1, 0, half).reshape({-1}).nonzero().squeeze(1);
    xl = xl.index_select(0, k), yl = yl.index_select(0, k);
  }
  LookFit out;
  out.map = torch::cat({torch::eye(3, torch::kDouble), torch::zeros({1, 3}, torch::kDouble)});  // the identity
  if (xl.size(0) >= 4) {
    const auto a = torch::cat({xl, torch::ones({xl.size(0), 1}, torch::kDouble)}, 1);  // (N,4)
    const auto ata = torch::matmul(a.t(), a), aty = torch::matmul(a.t(), yl);
    // Normal equations; a rank-deficient left half (flat colours) keeps the identity.
    if (torch::linalg_matrix_rank(ata).item<int64_t>() == 4) out.map = torch::linalg_solve(ata, aty);
  }
  const auto all = torch::cat({x.reshape({-1, 3}), torch::ones({h * w, 1}, torch::kDouble)}, 1);
  out.fitted = torch::matmul(all, out.map).clamp(0.0, 1.0).reshape({h, w, 3}).to(torch::kFloat);
  return out;
}

CodeFit fit_code_left_half(AbleNerf& model, const torch::Tensor& c2w, const Intrinsics& cam, const torch::Tensor& image,
                           const torch::Tensor& keep, double near, double far, const PhotoFitOptions& o,
                           const torch::Device& device) {
  AppearanceCodeImpl* codes = model->appearance_code();
  TORCH_CHECK(codes != nullptr, "fit_code_left_half: the model has no appearance codes");
  const auto& p = codes->parameter();
  CodeFit out;
  out.code = torch::zeros({1, p.size(1)}, p.options().device(device)).requires_grad_(true);
  out.fit =
      fit_to_photo(model, c2w, cam, image, allowed_pixels(image.size(0), image.size(1), keep, 0, image.size(1) / 2),
                   {out.code}, o, device, [&](const Rays& rays, const torch::Tensor&) {
                     ForwardOptions f;
                     f.appearance = out.code;
                     return model->forward(rays, near, far, f);
                   });
  out.code = out.code.detach();
  return out;
}

}  // namespace ablenerf
