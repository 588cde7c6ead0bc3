// Camera refinement (model/camera_refine.h): zero is the poses as given; each rotation is
// Rodrigues' closed form of its axis-angle; centred corrections ignore a common change; a photo's
// corrected rays are exactly the rays its
// corrected camera-to-world casts (against data/rays.h), with a refined focal length those of the
// camera with the scaled focal length; the gradients against central differences;
// weights carry the corrections into a model made without them.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>

#include "kernels/kernel_test_util.h"
#include "model/able_nerf.h"
#include "model/camera_refine.h"
#include "model/ipe.h"
#include "test_util.h"

namespace ablenerf {
namespace {

// Rodrigues: R = I + sin(a) K + (1 - cos(a)) K^2 for the unit axis's cross-product matrix K.
torch::Tensor rodrigues(double x, double y, double z) {
  const double a = std::sqrt(x * x + y * y + z * z);
  const auto opts = torch::TensorOptions().dtype(torch::kDouble);
  const auto k = torch::tensor({0.0, -z, y, z, 0.0, -x, -y, x, 0.0}, opts).view({3, 3}) / a;
  return torch::eye(3, opts) + std::sin(a) * k + (1 - std::cos(a)) * torch::matmul(k, k);
}

// Parameters c over the learning-rate scale: uncentred, the corrections are c.
CameraRefine with_corrections(const torch::Tensor& c, bool centred = false) {
  CameraRefine cr(c.size(0), kCameraRefineLrScale, centred);
  cr->to(torch::kDouble);
  torch::NoGradGuard no_grad;
  cr->parameter().copy_(c / cr->lr_scale());
  return cr;
}

TEST(CameraRefine, ZeroIsThePosesAsGivenAndRotationsAreRodrigues) {
  const Rays rays = test::random_rays(5, 1, torch::kDouble);
  const auto photo = torch::tensor({0, 1, 1, 0, 1}, torch::kLong);
  CameraRefine zero(2);
  zero->to(torch::kDouble);
  const Rays same = zero(rays, photo);
  EXPECT_TRUE(torch::equal(same.origins, rays.origins));
  EXPECT_TRUE(torch::equal(same.directions, rays.directions));
  EXPECT_TRUE(torch::equal(same.radii, rays.radii));

  const auto c = torch::tensor({{0.3, -0.2, 0.5, 0.0, 0.0, 0.0}, {-0.01, 0.02, 0.005, 0.0, 0.0, 0.0}}, torch::kDouble);
  const auto r = with_corrections(c)->rotations();
  EXPECT_LT(test::max_abs(r[0] - rodrigues(0.3, -0.2, 0.5)), 1e-12);
  EXPECT_LT(test::max_abs(r[1] - rodrigues(-0.01, 0.02, 0.005)), 1e-10);  // 1 - cos cancels at small angles
  EXPECT_THROW(CameraRefine(0), std::invalid_argument);
  EXPECT_THROW(CameraRefine(2, 0.0), std::invalid_argument);
}

// In training the corrections applied are the parameters minus their mean: the same shift and turn
// added to every camera's parameters changes no ray.
TEST(CameraRefine, CentredCorrectionsIgnoreACommonChange) {
  const Rays rays = test::random_rays(6, 5, torch::kDouble);
  const auto photo = torch::tensor({0, 1, 2, 2, 1, 0}, torch::kLong);
  const auto c = test::seeded_randn({3, 6}, 6) * 0.1;
  auto a = with_corrections(c, true), b = with_corrections(c + test::seeded_randn({1, 6}, 7) * 0.1, true);
  torch::NoGradGuard no_grad;
  const Rays ra = a(rays, photo), rb = b(rays, photo);
  EXPECT_LT(test::max_abs(ra.origins - rb.origins), 1e-12);
  EXPECT_LT(test::max_abs(ra.directions - rb.directions), 1e-12);
  EXPECT_LT(test::max_abs(a->correction().sum(0)), 1e-12);
  EXPECT_LT(test::max_abs(a->correction() - (c - c.mean(0, true))), 1e-12);
}

// With the cameras' centres set, the corrections applied are the parameters modulo the rig's gauge:
// adding a gauge motion (every camera turned by w, its centre moved by w x c_p + t + s (c_p - c))
// changes no correction, taking the gauge out twice is taking it out once, and a common turn of every
// camera about its own centre, which is no gauge motion, is kept: it becomes the same turn of the
// centres the other way about their mean (by hand: w' = 0, t'_p = -w x (c_p - c)).
TEST(CameraRefine, CorrectionsAreTakenModuloTheRigsGauge) {
  const auto c = test::seeded_randn({5, 6}, 8) * 0.1;
  const auto centres = test::seeded_randn({5, 3}, 9) * 2.0;
  const auto d = centres - centres.mean(0, true);
  const auto with_centres = [&](const torch::Tensor& p) {
    auto cr = with_corrections(p, true);
    cr->set_centres(centres);
    return cr;
  };
  const auto w = torch::tensor({0.02, -0.01, 0.03}, torch::kDouble),
             t = torch::tensor({0.1, 0.2, -0.1}, torch::kDouble);
  const double scale = 0.05;
  const auto gauge = torch::cat({w.expand({5, 3}), torch::cross(w.expand({5, 3}), centres, 1) + t + scale * d}, 1);
  auto a = with_centres(c), b = with_centres(c + gauge);
  torch::NoGradGuard no_grad;
  EXPECT_LT(test::max_abs(a->correction() - b->correction()), 1e-12);
  EXPECT_LT(test::max_abs(with_centres(a->correction())->correction() - a->correction()), 1e-12);
  EXPECT_LT(test::max_abs(with_centres(gauge)->correction()), 1e-12);
  const auto turn = with_centres(torch::cat({w.expand({5, 3}), torch::zeros({5, 3}, torch::kDouble)}, 1));
  const auto want = torch::cat({torch::zeros({5, 3}, torch::kDouble), -torch::cross(w.expand({5, 3}), d, 1)}, 1);
  EXPECT_LT(test::max_abs(turn->correction() - want), 1e-12);
  EXPECT_GT(test::max_abs(turn->correction()), 1e-3);
  EXPECT_THROW(a->set_centres(torch::zeros({4, 3}, torch::kDouble)), c10::Error);
}

// The corrected rays of a photo are the rays of its corrected camera: the same pixels cast through
// CameraRefine::corrected(c2w) by rays_for_pixels (a pinhole and a fisheye camera).
TEST(CameraRefine, CorrectedRaysAreTheCorrectedCamerasRays) {
  Intrinsics pin;
  pin.fx = 50, pin.fy = 55, pin.cx = 16, pin.cy = 12, pin.width = 32, pin.height = 24;
  Intrinsics fish = pin;
  fish.model = LensModel::Fisheye;
  fish.dist = {0.05, -0.01, 0, 0, 0, 0};
  const auto c2w = torch::tensor({{0.0, -0.6, 0.8, 2.0, 1.0, 0.0, 0.0, -1.0, 0.0, 0.8, 0.6, 3.0},
                                  {1.0, 0.0, 0.0, 0.5, 0.0, 1.0, 0.0, 0.25, 0.0, 0.0, 1.0, 4.0}},
                                 torch::kDouble)
                       .view({2, 3, 4});
  auto refine = with_corrections(
      torch::tensor({{0.04, -0.03, 0.02, 0.1, -0.05, 0.2}, {-0.02, 0.05, 0.01, -0.3, 0.1, 0.0}}, torch::kDouble));
  const auto photo = torch::tensor({0, 1, 0, 1, 1, 0}, torch::kLong);
  const auto col = torch::tensor({0, 5, 31, 16, 7, 20}, torch::kLong);
  const auto row = torch::tensor({0, 23, 11, 12, 3, 19}, torch::kLong);
  const auto cams = CameraTable::of({pin, fish}).index(photo);
  const Rays given = rays_for_pixels(c2w.index_select(0, photo), col, row, cams);
  torch::NoGradGuard no_grad;
  const Rays got = refine->forward(given, photo);
  const Rays want = rays_for_pixels(refine->corrected(c2w).index_select(0, photo), col, row, cams);
  // rays_for_pixels casts in float32.
  EXPECT_LT(test::max_abs(got.origins - want.origins), 1e-6);
  EXPECT_LT(test::max_abs(got.directions - want.directions), 1e-6);
  EXPECT_LT(test::max_abs(got.radii - want.radii), 1e-9);
  EXPECT_GT(test::max_abs(got.directions - given.directions), 0.01);  // it moved them
  // The corrected rotation is still a rotation.
  const auto r = refine->corrected(c2w).slice(2, 0, 3);
  EXPECT_LT(test::max_abs(torch::matmul(r, r.transpose(1, 2)) - torch::eye(3, torch::kDouble)), 1e-12);
}

// With the focal length refined, a photo's rays are those of its camera with focal length k fx, k fy
// (pinhole: exact), turned and shifted by its correction: rays_for_pixels through the scaled
// intrinsics and CameraRefine::corrected(c2w). Eval and render use refined(), the same scaled camera.
TEST(CameraRefine, RefinedFocalRaysAreTheScaledCamerasRays) {
  Intrinsics pin;
  pin.fx = 50, pin.fy = 55, pin.cx = 16, pin.cy = 12, pin.width = 32, pin.height = 24;
  const auto c2w = torch::tensor({{0.0, -0.6, 0.8, 2.0, 1.0, 0.0, 0.0, -1.0, 0.0, 0.8, 0.6, 3.0},
                                  {1.0, 0.0, 0.0, 0.5, 0.0, 1.0, 0.0, 0.25, 0.0, 0.0, 1.0, 4.0}},
                                 torch::kDouble)
                       .view({2, 3, 4});
  CameraRefine refine(2, kCameraRefineLrScale, /*centred=*/false, /*focal=*/true);
  refine->to(torch::kDouble);
  ASSERT_TRUE(refine->refines_focal());
  EXPECT_DOUBLE_EQ(refine->focal_scale_value(), 1.0);  // zero = the focal length as given
  const double k = 1.07;
  {
    torch::NoGradGuard no_grad;
    refine->parameter().copy_(
        torch::tensor({{0.04, -0.03, 0.02, 0.1, -0.05, 0.2}, {-0.02, 0.05, 0.01, -0.3, 0.1, 0.0}}, torch::kDouble) /
        refine->lr_scale());
    refine->named_parameters()["focal"].fill_(std::log(k) / refine->lr_scale());
  }
  refine->set_cameras(c2w);
  EXPECT_NEAR(refine->focal_scale_value(), k, 1e-12);
  const Intrinsics scaled = refine->refined(pin);
  EXPECT_NEAR(scaled.fx, k * 50, 1e-9);
  EXPECT_NEAR(scaled.fy, k * 55, 1e-9);
  EXPECT_EQ(scaled.cx, pin.cx);
  EXPECT_EQ(scaled.cy, pin.cy);
  const auto photo = torch::tensor({0, 1, 0, 1, 1, 0}, torch::kLong);
  const auto col = torch::tensor({0, 5, 31, 16, 7, 20}, torch::kLong);
  const auto row = torch::tensor({0, 23, 11, 12, 3, 19}, torch::kLong);
  const Rays given = rays_for_pixels(c2w.index_select(0, photo), col, row, CameraTable::of({pin, pin}).index(photo));
  torch::NoGradGuard no_grad;
  const Rays got = refine->forward(given, photo);
  const Rays want = rays_for_pixels(refine->corrected(c2w).index_select(0, photo), col, row,
                                    CameraTable::of({scaled, scaled}).index(photo));
  EXPECT_LT(test::max_abs(got.origins - want.origins), 1e-6);
  EXPECT_LT(test::max_abs(got.directions - want.directions), 1e-6);
  EXPECT_LT(test::max_abs(got.radii - want.radii), 1e-9);
  // Without the focal scale the same corrections give the given focal length's rays: it moved them.
  const Rays unscaled = rays_for_pixels(refine->corrected(c2w).index_select(0, photo), col, row,
                                        CameraTable::of({pin, pin}).index(photo));
  EXPECT_GT(test::max_abs(got.directions - unscaled.directions), 0.01);
}

// The focal scale's gradient against central differences (the directions' and radii's dependence
// on k), and the module refuses to cast without the cameras' axes.
TEST(CameraRefine, FocalGradientMatchesFiniteDifferences) {
  const Rays rays = test::random_rays(7, 2, torch::kDouble);
  const auto photo = torch::tensor({2, 0, 2, 1, 0, 2, 2}, torch::kLong);
  const auto gd = test::seeded_randn({7, 3}, 4), gr = test::seeded_randn(rays.radii.sizes().vec(), 6);
  const auto c2w = test::seeded_randn({3, 3, 4}, 7);
  const auto make = [&](const torch::Tensor& f) {
    CameraRefine cr(3, kCameraRefineLrScale, /*centred=*/false, /*focal=*/true);
    cr->to(torch::kDouble);
    torch::NoGradGuard no_grad;
    cr->named_parameters()["focal"].copy_(f / cr->lr_scale());
    cr->set_cameras(c2w);
    return cr;
  };
  const test::ScalarFunction f = [&](const std::vector<torch::Tensor>& in) {
    const Rays moved = make(in[0])(rays, photo);
    return (moved.directions * gd).sum() + (moved.radii * gr).sum();
  };
  const auto f0 = torch::tensor({0.05}, torch::kDouble);
  const auto numeric = test::numeric_gradient(f, {f0}, 0);
  CameraRefine cr = make(f0);
  const Rays moved = cr(rays, photo);
  ((moved.directions * gd).sum() + (moved.radii * gr).sum()).backward();
  const auto grad = cr->named_parameters()["focal"].grad() / cr->lr_scale();
  EXPECT_LT(test::max_abs(grad - numeric), 1e-7);
  EXPECT_GT(test::max_abs(numeric), 0.1);
  CameraRefine no_axes(3, kCameraRefineLrScale, /*centred=*/false, /*focal=*/true);
  no_axes->to(torch::kDouble);
  EXPECT_THROW(no_axes(rays, photo), c10::Error);
}

TEST(CameraRefine, GradientMatchesFiniteDifferences) {
  const Rays rays = test::random_rays(7, 2, torch::kDouble);
  const auto photo = torch::tensor({2, 0, 2, 1, 0, 2, 2}, torch::kLong);
  const auto go = test::seeded_randn({7, 3}, 3), gd = test::seeded_randn({7, 3}, 4);
  // The scalar at parameters in[0] (central differences run without autograd), centred as in training.
  const test::ScalarFunction f = [&](const std::vector<torch::Tensor>& in) {
    const Rays moved = with_corrections(in[0], true)(rays, photo);
    return (moved.origins * go).sum() + (moved.directions * gd).sum();
  };
  const auto c0 = test::seeded_randn({3, 6}, 5) * 0.2;
  const auto numeric = test::numeric_gradient(f, {c0}, 0);
  // The module's own gradient, through its parameter.
  CameraRefine cr = with_corrections(c0, true);
  const Rays moved = cr(rays, photo);
  ((moved.origins * go).sum() + (moved.directions * gd).sum()).backward();
  // The parameter is the corrections over the learning-rate scale.
  const auto grad = cr->parameter().grad() / cr->lr_scale();
  EXPECT_LT(test::max_abs(grad - numeric), 1e-7);
  EXPECT_GT(test::max_abs(numeric.slice(1, 0, 3)), 0.1);
  // Centred: a common change of every camera's parameters moves no ray, so the gradients sum to
  // zero over the cameras; photo 1's shift gets its ray's origin gradient minus a third of all of them.
  EXPECT_LT(test::max_abs(grad.sum(0)), 1e-12);
  EXPECT_LT(test::max_abs(grad[1].slice(0, 3, 6) - (go[3] - go.sum(0) / 3)), 1e-12);
}

// The closed form against ATen's matrix exponential of the same cross-product matrices, values and
// gradients, at angles on both sides of the series' threshold (q^2 = 1e-4), zero included; and in
// float32 against float64 (the closed form has no 1 - cos q to cancel).
TEST(CameraRefine, RotationsAndGradientsMatchTheMatrixExponential) {
  const std::vector<double> angles = {0.0, 1e-6, 1e-3, 0.0099, 0.0101, 0.3, 1.5, 3.0};
  const auto axes = torch::nn::functional::normalize(test::seeded_randn({static_cast<int64_t>(angles.size()), 3}, 11),
                                                     torch::nn::functional::NormalizeFuncOptions().dim(1));
  const auto c = torch::zeros({static_cast<int64_t>(angles.size()), 6}, torch::kDouble);
  c.slice(1, 0, 3).copy_(axes * torch::tensor(angles, torch::kDouble).unsqueeze(1));
  c.slice(1, 3, 6).copy_(test::seeded_randn({static_cast<int64_t>(angles.size()), 3}, 12));
  const auto g = test::seeded_randn({static_cast<int64_t>(angles.size()), 3, 3}, 13);

  auto cr = with_corrections(c);
  const auto r = cr->rotations();
  (r * g).sum().backward();
  const auto grad = cr->parameter().grad() / cr->lr_scale();  // d/d(correction) = d/d(parameter) / scale

  const auto w = c.slice(1, 0, 3).clone().requires_grad_(true);
  const auto zero = torch::zeros_like(w.select(1, 0));
  const auto x = w.select(1, 0), y = w.select(1, 1), z = w.select(1, 2);
  const auto k = torch::stack({zero, -z, y, z, zero, -x, -y, x, zero}, 1).view({-1, 3, 3});
  const auto ref = torch::matrix_exp(k);
  (ref * g).sum().backward();
  EXPECT_LT(test::max_abs(r.detach() - ref.detach()), 1e-12);
  EXPECT_LT(test::max_abs(grad.slice(1, 0, 3) - w.grad()), 1e-12);
  EXPECT_LT(test::max_abs(grad.slice(1, 3, 6)), 1e-15);  // the shift does not turn the camera
  // Rotations: orthonormal with determinant one.
  const auto rrt = torch::matmul(r, r.transpose(1, 2)).detach();
  EXPECT_LT(test::max_abs(rrt - torch::eye(3, torch::kDouble).expand_as(rrt)), 1e-14);

  CameraRefine f32(c.size(0), kCameraRefineLrScale, false);
  {
    torch::NoGradGuard no_grad;
    f32->parameter().copy_((c / f32->lr_scale()).to(torch::kFloat));
  }
  EXPECT_LT(test::max_abs(f32->rotations().to(torch::kDouble) - r.detach()), 1e-6);
}

// BARF's coarse-to-fine window: alpha by hand at the schedule's points; the weights of each band
// in closed form; against the IPE's layout, a window open on band 0 alone leaves exactly the
// degree-1 IPE's features (sines of band 0, then its cosines) and zeros elsewhere; a model with the
// window fully open renders as one without it, and one with band 0 alone does not.
TEST(CameraRefine, CoarseToFineWindowOpensOneBandAtATime) {
  EXPECT_DOUBLE_EQ(coarse_to_fine_alpha(0.0, 0.1, 0.5, 16), 1.0);
  EXPECT_DOUBLE_EQ(coarse_to_fine_alpha(0.1, 0.1, 0.5, 16), 1.0);
  EXPECT_DOUBLE_EQ(coarse_to_fine_alpha(0.3, 0.1, 0.5, 16), 8.5);
  EXPECT_DOUBLE_EQ(coarse_to_fine_alpha(0.5, 0.1, 0.5, 16), 16.0);
  EXPECT_DOUBLE_EQ(coarse_to_fine_alpha(0.9, 0.1, 0.5, 16), 16.0);
  const auto w = frequency_window_weights(2.5, 4);  // bands 0, 1 open, 2 half (1 - cos(pi/2)) / 2, 3 shut
  const std::vector<float> band = {1, 1, 0.5f, 0};
  ASSERT_EQ(w.numel(), 24);
  for (int64_t i = 0; i < 24; ++i) EXPECT_NEAR(w[i].item<float>(), band[static_cast<size_t>((i % 12) / 3)], 1e-7) << i;

  const auto mean = test::seeded_randn({5, 3}, 21), cov = test::seeded_randn({5, 3}, 22).abs() * 0.01;
  const auto f = integrated_pos_enc(mean, cov, 4) * frequency_window_weights(1.0, 4);
  const auto one = integrated_pos_enc(mean, cov, 1);  // (5, 6): 3 sines, 3 cosines
  EXPECT_TRUE(torch::equal(f.slice(1, 0, 3), one.slice(1, 0, 3)));
  EXPECT_TRUE(torch::equal(f.slice(1, 12, 15), one.slice(1, 3, 6)));
  EXPECT_EQ(f.slice(1, 3, 12).abs().max().item<float>(), 0.0f);
  EXPECT_EQ(f.slice(1, 15, 24).abs().max().item<float>(), 0.0f);

  torch::manual_seed(3);
  AbleNerf model(test::tiny_model_config().get<ModelConfig>());
  model->eval();
  torch::NoGradGuard no_grad;
  const Rays rays = test::random_rays(6, 23);
  const auto plain = model->forward(rays, 2.0, 6.0).rgb_fine;
  model->set_frequency_window(model->config().ipe_degrees);
  EXPECT_TRUE(torch::equal(model->forward(rays, 2.0, 6.0).rgb_fine, plain));
  model->set_frequency_window(1.0);
  EXPECT_GT((model->forward(rays, 2.0, 6.0).rgb_fine - plain).abs().max().item<float>(), 1e-4);
}

TEST(CameraRefine, WeightsCarryTheCorrectionsIntoAModelMadeWithoutThem) {
  test::TempDir dir;
  const ModelConfig cfg = test::tiny_model_config().get<ModelConfig>();
  AbleNerf a(cfg);
  a->enable_camera_refine(4);
  {
    torch::NoGradGuard no_grad;
    a->camera_refine()->parameter().copy_(torch::randn({4, 6}));
  }
  EXPECT_THROW(a->enable_camera_refine(4), std::logic_error);
  save_weights(a, dir / "w.pt");
  AbleNerf b(cfg);
  ASSERT_EQ(b->camera_refine(), nullptr);
  load_weights(b, dir / "w.pt");
  ASSERT_NE(b->camera_refine(), nullptr);
  EXPECT_TRUE(torch::equal(b->camera_refine()->correction(), a->camera_refine()->correction()));
  EXPECT_GT(test::max_abs(b->camera_refine()->correction()), 0.0);
  EXPECT_FALSE(b->camera_refine()->refines_focal());
  // With the focal scale: it comes back too.
  AbleNerf c(cfg);
  c->enable_camera_refine(4, /*focal=*/true);
  {
    torch::NoGradGuard no_grad;
    c->camera_refine()->named_parameters()["focal"].fill_(0.3);
  }
  save_weights(c, dir / "wf.pt");
  AbleNerf d(cfg);
  load_weights(d, dir / "wf.pt");
  ASSERT_NE(d->camera_refine(), nullptr);
  ASSERT_TRUE(d->camera_refine()->refines_focal());
  EXPECT_DOUBLE_EQ(d->camera_refine()->focal_scale_value(), c->camera_refine()->focal_scale_value());
  EXPECT_GT(d->camera_refine()->focal_scale_value(), 1.0);
}

}  // namespace
}  // namespace ablenerf
