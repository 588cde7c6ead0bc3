// NeRF-W's code fit (eval/look_fit.h, fit_code_left_half) and the loop beneath it (eval/photo_fit.h).
// The truth is known: a photo rendered by the model itself with a chosen appearance code. The code
// fitted on the photo's left half must render the right half, which the fit never saw, far closer
// than the mean look does, and the model's own parameters must come out untouched, without a .grad.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <vector>

#include "eval/camera_path.h"
#include "eval/look_fit.h"
#include "eval/photo_fit.h"
#include "eval/renderer.h"
#include "model/able_nerf.h"
#include "test_util.h"

namespace ablenerf {
namespace {

TEST(PhotoFit, AllowedPixelsAreTheKeptOnesOfTheColumns) {
  auto keep = torch::ones({2, 4}, torch::kBool);
  keep[1][0] = false;
  // Row-major indices into 2 x 4: columns 0-1 are 0, 1, 4, 5; pixel 4 (row 1, column 0) is masked.
  EXPECT_TRUE(torch::equal(allowed_pixels(2, 4, keep, 0, 2), torch::tensor({0, 1, 5}, torch::kLong)));
  EXPECT_TRUE(torch::equal(allowed_pixels(2, 4, {}, 2, 4), torch::tensor({2, 3, 6, 7}, torch::kLong)));
  EXPECT_EQ(allowed_pixels(2, 4, {}, 3, 9).numel(), 2);  // clamped to the image
}

TEST(LookFit, CodeFittedOnTheLeftHalfRendersTheRightHalf) {
  torch::manual_seed(3);
  AbleNerf model(test::small_le_model_config());
  model->enable_appearance_code(3);
  model->eval();
  const Intrinsics cam = test::pinhole(16, 12, 14.0, 14.0, 8.0, 6.0);
  const auto c2w = look_at(torch::tensor({0.0f, -4.0f, 1.0f}), torch::zeros({3}), torch::tensor({0.0f, 0.0f, 1.0f}));
  const auto torch_cpu = torch::Device(torch::kCPU);
  // The photo: the model's render with a code of trained codes' size (entries a few tenths).
  ForwardOptions truth;
  truth.appearance = 0.3 * torch::randn({1, 16});
  const auto photo = render_image(model, c2w, cam, 2.0, 6.0, 4096, truth, torch_cpu).rgb;
  const auto mean_look = render_image(model, c2w, cam, 2.0, 6.0, 4096, ForwardOptions{}, torch_cpu).rgb;

  std::vector<torch::Tensor> before;
  for (const auto& p : model->parameters()) before.push_back(p.detach().clone());
  PhotoFitOptions o;
  o.steps = 150;
  o.rays = 96;  // the left half has 96 pixels
  o.lr = 1e-2;
  const CodeFit fit = fit_code_left_half(model, c2w, cam, photo, {}, 2.0, 6.0, o, torch_cpu);
  ASSERT_EQ(fit.code.sizes(), (std::vector<int64_t>{1, 16}));
  EXPECT_FALSE(fit.code.requires_grad());
  EXPECT_LT(fit.fit.mse_after, 0.1 * fit.fit.mse_before);

  ForwardOptions fitted;
  fitted.appearance = fit.code;
  const auto render = render_image(model, c2w, cam, 2.0, 6.0, 4096, fitted, torch_cpu).rgb;
  const auto right_mse = [&](const torch::Tensor& x) { return (x - photo).slice(1, 8).pow(2).mean().item<double>(); };
  ASSERT_GT(right_mse(mean_look), 1e-6);  // the code changes the photo
  EXPECT_LT(right_mse(render), 0.1 * right_mse(mean_look));

  const auto params = model->parameters();
  for (size_t i = 0; i < params.size(); ++i) {
    EXPECT_TRUE(torch::equal(params[i], before[i])) << i;
    EXPECT_FALSE(params[i].grad().defined()) << i;
  }
  EXPECT_FALSE(model->is_training());  // left as it was
  // A model without codes is refused.
  AbleNerf plain(test::small_le_model_config());
  EXPECT_THROW(fit_code_left_half(plain, c2w, cam, photo, {}, 2.0, 6.0, o, torch_cpu), c10::Error);
}

}  // namespace
}  // namespace ablenerf
