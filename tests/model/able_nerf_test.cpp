// Stage 8: the assembled model: parameter counts of the presets (docs/MODEL.md, section 11), output contract,
// gradient paths, the no-LE and no-mask ablations, the branch split and LE perturbation.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <tuple>
#include <utility>

#include "model/able_nerf.h"
#include "model/compute.h"
#include "kernels/bf16_gemm.h"
#include "kernels/token_product.h"
#include "util/errors.h"
#include "kernels/cpu_parallel.h"
#include "model/tonemap.h"
#include "test_util.h"
#include "model/compute_config.h"
#include "model/model_config.h"
#include "data/data_config.h"

namespace ablenerf {
namespace {

ModelConfig tiny() {
  ModelConfig m;
  m.width = 32;
  m.heads = 2;
  m.ff_ratio = 2;
  m.coarse_layers = 2;
  m.fine_layers = 2;
  m.samples = 16;
  m.ipe_degrees = 8;
  m.le_count = 4;
  m.le_layers = 1;
  return m;
}

Rays some_rays(int64_t b) { return test::random_rays(b, 99); }

TEST(AbleNerf, PresetParameterCounts) {
  EXPECT_EQ(AbleNerf(test::preset_config("blender").get<ModelConfig>())->parameter_count(),
            6163404);  // docs/MODEL.md, section 11
  EXPECT_EQ(AbleNerf(test::preset_config("shiny").get<ModelConfig>())->parameter_count(), 6160332);  // 16 LE
  EXPECT_GT(AbleNerf(test::preset_config("demo").get<ModelConfig>())->parameter_count(), 0);
}

TEST(AbleNerf, CapturePresetReadsTheGridAndPlacesSamplesByTheProposal) {
  // configs/capture.toml and its GPU variant capture_gpu.toml (the presets for real captures,
  // docs/BENCHMARKS.md): both of ablenerf's extensions on, the paper's presets with neither.
  for (const char* name : {"capture", "capture_gpu"}) {
    const AbleNerf capture(test::preset_config(name).get<ModelConfig>());
    EXPECT_NE(capture->grid(), nullptr) << name;
    ASSERT_NE(capture->proposal(), nullptr) << name;
    EXPECT_EQ(capture->proposal()->samples(), 32) << name;
    // and forward-facing captures contracted, not in NDC (docs/benchmarks/history.md, "A forward-facing capture").
    EXPECT_FALSE(test::preset_config(name).get<DataConfig>().ndc) << name;
  }
  for (const char* paper : {"blender", "demo"}) {
    const AbleNerf m(test::preset_config(paper).get<ModelConfig>());
    EXPECT_EQ(m->grid(), nullptr) << paper;
    EXPECT_EQ(m->proposal(), nullptr) << paper;
  }
}

TEST(AbleNerf, OutputContract) {
  torch::manual_seed(1);
  AbleNerf model(tiny());
  model->eval();
  const int64_t b = 5, s = 16;
  const auto out = model->forward(some_rays(b), 2.0, 6.0);
  ASSERT_EQ(out.rgb_coarse.sizes(), (std::vector<int64_t>{b, 3}));
  ASSERT_EQ(out.rgb_fine.sizes(), (std::vector<int64_t>{b, 3}));
  ASSERT_EQ(out.coarse_weights.sizes(), (std::vector<int64_t>{b, s}));
  ASSERT_EQ(out.fine_weights.sizes(), (std::vector<int64_t>{b, s}));
  ASSERT_EQ(out.fine_t.sizes(), (std::vector<int64_t>{b, s + 1}));
  EXPECT_GE(out.rgb_fine.min().item<double>(), 0.0);
  EXPECT_LE(out.rgb_fine.max().item<double>(), 1.0);
  EXPECT_TRUE(torch::all(out.fine_t.slice(1, 1) >= out.fine_t.slice(1, 0, s)).item<bool>());
  EXPECT_GE(out.fine_t.min().item<double>(), 2.0);
  EXPECT_LE(out.fine_t.max().item<double>(), 6.0);
  const auto sums = out.coarse_weights.sum(1);
  EXPECT_TRUE(torch::all(sums > 0).item<bool>() && torch::all(sums < 1).item<bool>());
  EXPECT_FALSE(out.coarse_weights.requires_grad());
  // Deterministic in eval mode; rays are independent of their batch mates.
  const auto again = model->forward(some_rays(b).slice(1, 3), 2.0, 6.0);
  EXPECT_TRUE(torch::allclose(again.rgb_fine, out.rgb_fine.slice(0, 1, 3), 1e-5, 1e-6));
}

TEST(AbleNerf, FineLossTrainsTheCoarseStackThroughTheRayToken) {
  torch::manual_seed(2);
  AbleNerf model(tiny());
  const auto out = model->forward(some_rays(4), 2.0, 6.0);
  out.rgb_fine.sum().backward();
  const auto named = model->named_parameters();
  EXPECT_GT(named["coarse.blocks.1.ff_out.weight"].grad().abs().sum().item<double>(), 0.0);
  EXPECT_GT(named["ray_token"].grad().abs().sum().item<double>(), 0.0);
  EXPECT_GT(named["le"].grad().abs().sum().item<double>(), 0.0);
  // The coarse colour heads only serve the coarse loss.
  EXPECT_FALSE(named["ray_head_coarse.linear.weight"].grad().defined() &&
               named["ray_head_coarse.linear.weight"].grad().abs().sum().item<double>() > 0);
}

TEST(AbleNerf, NearGradientScalingMultipliesEachSampleTokensGradientBySquaredDepth) {
  // The closed form: d/dx sum(w * f(x)) = w * min(1, (t_mid / d)^2) per sample, the values unchanged.
  torch::manual_seed(3);
  const auto x = torch::randn({2, 3, 4}, torch::dtype(torch::kDouble).requires_grad(true));
  const auto t = torch::tensor({{0.0, 0.2, 0.6, 3.0}, {1.0, 1.5, 2.5, 4.5}}, torch::kDouble);
  const auto w = torch::randn({2, 3, 4}, torch::kDouble);
  const auto y = near_gradient_scaled(x * 1.0, t, 2.0);
  EXPECT_TRUE(torch::equal(y, x));
  (y * w).sum().backward();
  // Middles 0.1, 0.4, 1.8 and 1.25, 2, 3.5 over d = 2: (0.05)^2, (0.2)^2, (0.9)^2, (0.625)^2, then 1, 1.
  const auto factor = torch::tensor({{0.0025, 0.04, 0.81}, {0.390625, 1.0, 1.0}}, torch::kDouble).unsqueeze(-1);
  EXPECT_TRUE(torch::allclose(x.grad(), w * factor, 1e-12, 1e-14));
  EXPECT_THROW(near_gradient_scaled(x * 1.0, t.slice(1, 0, 3), 2.0), c10::Error);
}

TEST(AbleNerf, NearGradientScalingLeavesTheOutputsAndEveryPathBesideTheSampleTokens) {
  const auto grads = [](double distance) {
    torch::manual_seed(4);
    AbleNerf model(tiny());
    ForwardOptions opts;
    opts.near_gradient_distance = distance;
    const auto out = model->forward(some_rays(6), 2.0, 6.0, opts);
    (out.rgb_fine.sum() + out.rgb_coarse.sum()).backward();
    const auto named = model->named_parameters();
    return std::make_tuple(out.rgb_fine.detach(), named["volume_embedding.linear0.weight"].grad().clone(),
                           named["ray_head_fine.linear.weight"].grad().clone());
  };
  const auto [rgb_off, embed_off, head_off] = grads(0.0);
  // Samples between the near plane 2 and 6: a distance of 1 scales nothing.
  const auto [rgb_1, embed_1, head_1] = grads(1.0);
  EXPECT_TRUE(torch::equal(rgb_1, rgb_off));
  EXPECT_TRUE(torch::equal(embed_1, embed_off));
  // A distance of 100 scales every sample by (t / 100)^2 <= 0.0036: the tokens' embedding learns
  // less, the colour head (no sample token below it) as before.
  const auto [rgb_100, embed_100, head_100] = grads(100.0);
  EXPECT_TRUE(torch::equal(rgb_100, rgb_off));
  EXPECT_TRUE(torch::allclose(head_100, head_off, 1e-6, 1e-7));
  EXPECT_LT(embed_100.norm().item<double>(), 0.01 * embed_off.norm().item<double>());
}

TEST(AbleNerf, BranchesRecombineToTheOutput) {
  torch::manual_seed(3);
  AbleNerf model(tiny());
  ForwardOptions opts;
  opts.branches = true;
  const auto out = model->forward(some_rays(6), 2.0, 6.0, opts);
  EXPECT_TRUE(torch::allclose(out.rgb_fine, tonemap(out.ray_colour_fine, out.le_colour_fine)));
  EXPECT_TRUE(torch::allclose(out.rgb_coarse, tonemap(out.ray_colour_coarse, out.le_colour_coarse)));
  EXPECT_LE(out.le_colour_fine.max().item<double>(), 0.5);
}

TEST(AbleNerf, NoLEAblationHasNoLEBranch) {
  auto cfg = tiny();
  cfg.le_count = 0;
  torch::manual_seed(4);
  AbleNerf model(cfg);
  for (const auto& p : model->named_parameters()) EXPECT_EQ(p.key().rfind("le", 0), std::string::npos) << p.key();
  ForwardOptions opts;
  opts.branches = true;
  const auto out = model->forward(some_rays(3), 2.0, 6.0, opts);
  EXPECT_TRUE(torch::equal(out.le_colour_fine, torch::zeros_like(out.le_colour_fine)));
  EXPECT_TRUE(torch::allclose(out.rgb_fine, tonemap(out.ray_colour_fine, torch::Tensor())));
}

TEST(AbleNerf, MaskFlagChangesTheResult) {
  auto cfg = tiny();
  torch::manual_seed(5);
  AbleNerf masked(cfg);
  cfg.mask = false;
  torch::manual_seed(5);
  AbleNerf open(cfg);
  const auto rays = some_rays(3);
  EXPECT_FALSE(torch::allclose(masked->forward(rays, 2, 6).rgb_fine, open->forward(rays, 2, 6).rgb_fine));
}

TEST(AbleNerf, LEPerturbationIsReproducibleAndChangesOnlyTheLEColour) {
  torch::manual_seed(6);
  AbleNerf model(tiny());
  model->eval();
  const auto rays = some_rays(4);
  ForwardOptions base;
  base.branches = true;
  ForwardOptions noisy = base;
  noisy.le_noise = 1.0;
  ForwardOptions zero = base;
  zero.le_zero = true;
  const auto a = model->forward(rays, 2, 6, base), n1 = model->forward(rays, 2, 6, noisy),
             n2 = model->forward(rays, 2, 6, noisy), z = model->forward(rays, 2, 6, zero);
  EXPECT_TRUE(torch::equal(n1.rgb_fine, n2.rgb_fine));  // same noise for every call/chunk
  EXPECT_FALSE(torch::allclose(a.le_colour_fine, n1.le_colour_fine));
  EXPECT_FALSE(torch::allclose(a.le_colour_fine, z.le_colour_fine));
  EXPECT_TRUE(torch::equal(a.ray_colour_fine, z.ray_colour_fine));
}

TEST(AbleNerf, JitterOnlyInTrainingMode) {
  auto cfg = tiny();
  cfg.randomized = true;
  torch::manual_seed(7);
  AbleNerf model(cfg);
  const auto rays = some_rays(2);
  torch::Generator g1 = at::detail::createCPUGenerator(1), g2 = at::detail::createCPUGenerator(2);
  ForwardOptions o1, o2;
  o1.generator = &g1;
  o2.generator = &g2;
  model->train();
  EXPECT_FALSE(torch::allclose(model->forward(rays, 2, 6, o1).fine_t, model->forward(rays, 2, 6, o2).fine_t));
  model->eval();
  EXPECT_TRUE(torch::equal(model->forward(rays, 2, 6, o1).fine_t, model->forward(rays, 2, 6, o2).fine_t));
}

void expect_same(const torch::Tensor& a, const torch::Tensor& b, double tol, const char* what) {
  ASSERT_TRUE(a.defined() && b.defined()) << what;
  ASSERT_EQ(a.sizes(), b.sizes()) << what;
  EXPECT_LT((a - b).abs().max().item<double>(), tol) << what;
}

// The tiny model in float64 on six rays, forward with the branch colours and default options, then
// with `changed` (its branches set too): the pair (full, changed).
std::pair<ModelOutput, ModelOutput> full_and_changed_forward(ForwardOptions changed) {
  torch::manual_seed(5);
  AbleNerf model(tiny());
  model->to(torch::kDouble);
  model->eval();
  const Rays r = some_rays(6);
  const Rays rays{r.origins.to(torch::kDouble), r.directions.to(torch::kDouble), r.radii.to(torch::kDouble)};
  torch::NoGradGuard no_grad;
  ForwardOptions full_opts;
  full_opts.branches = true;
  changed.branches = true;
  return {model->forward(rays, 2.0, 6.0, full_opts), model->forward(rays, 2.0, 6.0, changed)};
}

// Everything a render reads (both passes' attention, the fine colour and its branches, the fine
// depths) is the same in both outputs (float64: exact up to summation order).
void expect_fine_outputs_same(const ModelOutput& a, const ModelOutput& b) {
  expect_same(a.rgb_fine, b.rgb_fine, 1e-12, "rgb_fine");
  expect_same(a.fine_weights, b.fine_weights, 1e-12, "fine_weights");
  expect_same(a.coarse_weights, b.coarse_weights, 1e-12, "coarse_weights");
  expect_same(a.fine_t, b.fine_t, 1e-12, "fine_t");
  expect_same(a.ray_colour_fine, b.ray_colour_fine, 1e-12, "ray_colour_fine");
  expect_same(a.le_colour_fine, b.le_colour_fine, 1e-12, "le_colour_fine");
}

TEST(AbleNerf, RenderingForwardSkipsOnlyTheCoarseColour) {
  // Without the coarse colour the last coarse layer computes the ray token's row alone and the
  // coarse LE branch is skipped; everything a render uses must be unchanged (float64: exact up to
  // summation order).
  ForwardOptions render_opts;
  render_opts.coarse.colour = false;
  const auto [full, render] = full_and_changed_forward(render_opts);
  expect_fine_outputs_same(render, full);
  EXPECT_FALSE(render.rgb_coarse.defined());
  EXPECT_FALSE(render.le_colour_coarse.defined());
  EXPECT_TRUE(full.rgb_coarse.defined());
}

TEST(AbleNerf, ACoarseColourWithoutItsLEChangesNothingElse) {
  // train.coarse_le = false: the coarse colour from the coarse ray token alone (its LE branch
  // skipped, the last coarse layer computing the ray token's row alone); the ray token, both
  // passes' attention and every fine output are those of the full forward.
  ForwardOptions no_le;
  no_le.coarse.le = false;
  const auto [full, cheap] = full_and_changed_forward(no_le);
  expect_fine_outputs_same(cheap, full);
  expect_same(cheap.ray_colour_coarse, full.ray_colour_coarse, 1e-12, "ray_colour_coarse");
  // The outputs are float32 (ModelOutput): the tone map of the float32 ray colour agrees to rounding.
  expect_same(cheap.rgb_coarse, tonemap(full.ray_colour_coarse, torch::Tensor()), 1e-6, "rgb_coarse");
  EXPECT_EQ(cheap.le_colour_coarse.abs().max().item<double>(), 0.0);
  EXPECT_GT(full.le_colour_coarse.abs().max().item<double>(), 0.0);
}

TEST(AbleNerf, ACoarseViewHeadReadsTheRayTokenAndChangesNothingElse) {
  // train.coarse_view_head: without the coarse LE transformer, the coarse LE colour head reads the
  // coarse ray token and the view code. Every fine output and the coarse ray colour are the full
  // forward's, the coarse colour is the tone map of its two branches, and the branch is the head's
  // own: with the head's last layer set to weights 0 and bias b it is 0.5 sigmoid(b) on every ray.
  ForwardOptions head;
  head.coarse.le = false;
  head.coarse.view_head = true;
  const auto [full, viewed] = full_and_changed_forward(head);
  expect_fine_outputs_same(viewed, full);
  expect_same(viewed.ray_colour_coarse, full.ray_colour_coarse, 1e-12, "ray_colour_coarse");
  expect_same(viewed.rgb_coarse, tonemap(viewed.ray_colour_coarse, viewed.le_colour_coarse), 1e-6, "rgb_coarse");
  EXPECT_GT(viewed.le_colour_coarse.abs().max().item<double>(), 0.0);
  EXPECT_GT((viewed.le_colour_coarse - full.le_colour_coarse).abs().max().item<double>(), 1e-6)
      << "the head read the LE transformer's output, not the ray token";

  torch::manual_seed(5);
  AbleNerf model(tiny());
  model->to(torch::kDouble);
  model->eval();
  const auto params = model->named_parameters();
  {
    torch::NoGradGuard no_grad;
    params["le_head_coarse.out.weight"].zero_();
    params["le_head_coarse.out.bias"].copy_(torch::tensor({-1.0, 0.0, 2.0}, torch::kDouble));
  }
  const Rays r = some_rays(6);
  const Rays rays{r.origins.to(torch::kDouble), r.directions.to(torch::kDouble), r.radii.to(torch::kDouble)};
  head.branches = true;
  torch::NoGradGuard no_grad;
  const auto out = model->forward(rays, 2.0, 6.0, head);
  const auto want = (0.5 * torch::sigmoid(torch::tensor({-1.0, 0.0, 2.0}, torch::kDouble))).expand({6, 3});
  expect_same(out.le_colour_coarse.to(torch::kDouble), want, 1e-7, "le_colour_coarse");
}

TEST(AbleNerf, RayParallelInferenceEqualsOneBatch) {
  if (!blas_thread_control_available()) GTEST_SKIP() << "no OpenBLAS thread control: always serial";
  const test::IntraOpThreads threads(2);
  torch::manual_seed(6);
  AbleNerf model(tiny());
  model->eval();
  const int64_t b = 40;
  ASSERT_GE(cpu_workers(b, 8), 2);
  const Rays rays = some_rays(b);
  torch::NoGradGuard no_grad;
  ForwardOptions opts;
  opts.branches = true;
  Compute ops;
  ops.cpu_split = CpuSplit::Ops;
  model->set_compute(ops);
  const auto one = model->forward(rays, 2.0, 6.0, opts);
  model->set_compute(Compute{});
  const auto split = model->forward(rays, 2.0, 6.0, opts);
  for (const auto& [a, c, what] : {std::make_tuple(one.rgb_fine, split.rgb_fine, "rgb_fine"),
                                   std::make_tuple(one.rgb_coarse, split.rgb_coarse, "rgb_coarse"),
                                   std::make_tuple(one.fine_weights, split.fine_weights, "fine_weights"),
                                   std::make_tuple(one.fine_t, split.fine_t, "fine_t"),
                                   std::make_tuple(one.le_colour_fine, split.le_colour_fine, "le_colour_fine")})
    expect_same(a, c, 1e-5, what);
  // The rays keep their order: a permuted batch would differ by far more than the tolerance.
  EXPECT_GT((split.rgb_fine - split.rgb_fine.flip(0)).abs().max().item<double>(), 1e-3);
}

// A CPU inference forward over more rays than a piece (AbleNerfImpl::forward_pieces, 512 rays a
// thread) gives every ray what a batch of 100 gives it, on the ray split and on one thread.
TEST(AbleNerf, InferenceInPiecesEqualsSmallBatches) {
  const test::IntraOpThreads threads(2);
  torch::manual_seed(7);
  AbleNerf model(tiny());
  model->eval();
  const int64_t b = 1300;  // over two pieces a thread on two threads, three on one
  const Rays rays = some_rays(b);
  torch::NoGradGuard no_grad;
  ForwardOptions opts;
  opts.branches = true;
  for (const CpuSplit split : {CpuSplit::Rays, CpuSplit::Ops}) {
    Compute c;
    c.cpu_split = split;
    model->set_compute(c);
    const auto whole = model->forward(rays, 2.0, 6.0, opts);
    std::vector<torch::Tensor> rgb, weights, le;
    for (int64_t lo = 0; lo < b; lo += 100) {
      const auto part = model->forward(rays.slice(lo, std::min(b, lo + 100)), 2.0, 6.0, opts);
      rgb.push_back(part.rgb_fine);
      weights.push_back(part.fine_weights);
      le.push_back(part.le_colour_fine);
    }
    expect_same(whole.rgb_fine, torch::cat(rgb), 1e-6, "rgb_fine");
    expect_same(whole.fine_weights, torch::cat(weights), 1e-6, "fine_weights");
    expect_same(whole.le_colour_fine, torch::cat(le), 1e-6, "le_colour_fine");
    EXPECT_GT((whole.rgb_fine - whole.rgb_fine.roll(1, 0)).abs().max().item<double>(), 1e-3);
  }
  model->set_compute(Compute{});
}

// compute.precision = "bf16" on a CPU: taken where the CPU has AMX tiles, else refused naming the
// key (or, for a run's saved config, fallen back to fp32); "auto" resolved to whichever runs; the
// scope switches the token products.
TEST(Compute, Bf16OnACpuIsTakenWithTilesAndRefusedWithout) {
  ComputeConfig cc;
  cc.precision = Precision::Bf16;
  const torch::Device cpu(torch::kCPU);
  if (cpu_has_bf16_products()) {
    EXPECT_EQ(Compute::from_config(cc, cpu, "run.toml").precision, Precision::Bf16);
    {
      const AutocastScope scope(Precision::Bf16, cpu);
      EXPECT_TRUE(token_products_bf16());
    }
    EXPECT_FALSE(token_products_bf16());
  } else {
    try {
      (void)Compute::from_config(cc, cpu, "run.toml");
      ADD_FAILURE() << "bf16 taken on a CPU without AMX";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("compute.precision"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("run.toml"), std::string::npos) << e.what();
    }
    EXPECT_THROW(AutocastScope(Precision::Bf16, cpu), std::invalid_argument);
  }
  EXPECT_EQ(Compute::from_config(cc, cpu, "run.toml", /*bf16_falls_back=*/true).precision,
            cpu_has_bf16_products() ? Precision::Bf16 : Precision::Fp32);
  // "auto": bf16 where it runs, fp32 elsewhere, never refused.
  cc.precision = Precision::Auto;
  EXPECT_EQ(Compute::from_config(cc, cpu, "run.toml").precision,
            cpu_has_bf16_products() ? Precision::Bf16 : Precision::Fp32);
}

// The whole model in bf16 on the ray split's threads: near its fp32 output, not equal to it, and
// its gradients near fp32's.
TEST(AbleNerf, Bf16ForwardAndBackwardStayNearFp32) {
  if (!cpu_has_bf16_products()) GTEST_SKIP() << "no AMX bfloat16 tiles on this CPU";
  const test::IntraOpThreads threads(2);
  torch::manual_seed(11);
  AbleNerf model(tiny());
  const Rays rays = some_rays(600);
  std::vector<torch::Tensor> rgb, grads;
  for (const Precision p : {Precision::Fp32, Precision::Bf16}) {
    Compute c;
    c.precision = p;
    model->set_compute(c);
    model->zero_grad();
    const auto out = model->forward(rays, 2.0, 6.0, ForwardOptions{});
    out.rgb_fine.square().sum().backward();
    rgb.push_back(out.rgb_fine.detach());
    std::vector<torch::Tensor> g;
    for (const auto& param : model->parameters())
      if (param.grad().defined()) g.push_back(param.grad().flatten());
    grads.push_back(torch::cat(g));
  }
  model->set_compute(Compute{});
  const double diff = (rgb[1] - rgb[0]).abs().max().item<double>();
  EXPECT_GT(diff, 1e-6) << "the bf16 products were not taken";
  EXPECT_LT(diff, 0.02);
  const double gscale = grads[0].abs().max().item<double>();
  EXPECT_LT((grads[1] - grads[0]).abs().max().item<double>(), 0.05 * gscale);
  EXPECT_GT(torch::cosine_similarity(grads[0], grads[1], 0).item<double>(), 0.999);
}

}  // namespace
}  // namespace ablenerf
