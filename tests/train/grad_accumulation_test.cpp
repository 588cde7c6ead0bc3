// One training step's forward + backward (train/grad_accumulation.h): the loss is the weighted
// MSE of the whole batch, and the gradients of the ray-parallel CPU path equal those of one
// loss.backward() over the whole batch (float64, so only summation order separates them).
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <string>
#include <vector>

#include "model/compute.h"
#include "kernels/cpu_parallel.h"
#include "test_util.h"
#include "train_fixture.h"
#include "train/grad_accumulation.h"
#include "train/regularisers.h"
#include "train/train_config.h"
#include "model/compute_config.h"

namespace ablenerf {
namespace {

RayBatch some_batch(int64_t n) {
  auto gen = at::detail::createCPUGenerator(18);
  return {test::random_rays(n, 17, torch::kDouble), torch::rand({n, 3}, gen, torch::kDouble), torch::Tensor()};
}

// Reference: the whole batch in one forward, the loss written out, one backward.
std::vector<torch::Tensor> reference_gradients(AbleNerf& model, const RayBatch& batch, const TrainConfig& tc,
                                               double* loss) {
  for (auto& p : model->parameters()) p.mutable_grad() = torch::Tensor();
  const auto out = model->forward(batch.rays, 2.0, 6.0);
  const auto mse_c = (out.rgb_coarse - batch.target).pow(2).mean();
  const auto mse_f = (out.rgb_fine - batch.target).pow(2).mean();
  const auto l = tc.coarse_weight * mse_c + tc.fine_weight * mse_f;
  l.backward();
  *loss = l.item<double>();
  std::vector<torch::Tensor> g;
  for (auto& p : model->parameters()) g.push_back(p.grad().clone());
  return g;
}

// Every parameter's gradient equals the reference's to float64 summation-order tolerance.
void expect_gradients_equal(AbleNerf& model, const std::vector<torch::Tensor>& ref, const std::string& what) {
  const auto params = model->parameters();
  for (size_t i = 0; i < params.size(); ++i) {
    ASSERT_TRUE(params[i].grad().defined()) << i;
    EXPECT_LT((params[i].grad() - ref[i]).abs().max().item<double>(), 1e-12 * (1 + ref[i].abs().max().item<double>()))
        << "parameter " << i << ", " << what;
  }
}

// test::two_head_model() in float64, training, its parameters drawn with `seed`.
AbleNerf double_model(uint64_t seed) {
  torch::manual_seed(seed);
  AbleNerf model(test::two_head_model());
  model->to(torch::kDouble);
  model->train();
  return model;
}

// Without a weight on the coarse colour the step does not compute it: the parameters that only
// make it (the coarse colour heads, the coarse LE transformer) get no gradient, where the reference
// (the colour computed and weighted 0) gives them exactly zero, and every other gradient and the
// loss are the reference's.
TEST(GradAccumulation, AZeroCoarseWeightSkipsTheCoarseColour) {
  const test::IntraOpThreads threads(2);
  AbleNerf model = double_model(9);
  TrainConfig tc;
  tc.coarse_weight = 0.0;
  const int64_t n = 24;
  const RayBatch batch = some_batch(n);
  double ref_loss = 0;
  const auto ref = reference_gradients(model, batch, tc, &ref_loss);
  for (auto& p : model->parameters()) p.mutable_grad() = torch::Tensor();
  const StepSums s = accumulate_gradients(model, batch, n, tc, n, 2.0, 6.0);
  EXPECT_NEAR(s.loss.item<double>(), ref_loss, 1e-12);
  EXPECT_EQ(s.terms[kTermCoarse].item<double>(), 0.0);
  const auto named = model->named_parameters();
  int skipped = 0;
  for (size_t i = 0; i < named.size(); ++i) {
    const auto& p = named[i].value();
    const std::string& name = named[i].key();
    if (!p.grad().defined()) {
      ++skipped;
      EXPECT_EQ(ref[i].abs().max().item<double>(), 0.0) << name << " has a gradient the skipped colour would give";
      EXPECT_TRUE(name.rfind("ray_head_coarse.", 0) == 0 || name.rfind("le_head_coarse.", 0) == 0 ||
                  name.rfind("le_coarse.", 0) == 0 || name.rfind("coarse.", 0) == 0)
          << name << " got no gradient";
      continue;
    }
    EXPECT_LT((p.grad() - ref[i]).abs().max().item<double>(), 1e-12 * (1 + ref[i].abs().max().item<double>())) << name;
  }
  EXPECT_GT(skipped, 0) << "the coarse colour was computed";
}

// A step with the coarse colour's loss at weight 0.3 and `tc`'s coarse settings: its loss is the
// one written out with the forward's colours under the same options, and the parameters named by
// `untrained` (a prefix each) get no gradient while every other does.
void expect_coarse_variant_step(AbleNerf& model, TrainConfig tc, const std::vector<std::string>& untrained) {
  const test::IntraOpThreads threads(2);
  tc.coarse_weight = 0.3;
  const int64_t n = 24;
  const RayBatch batch = some_batch(n);
  ForwardOptions opts;
  opts.coarse.le = tc.coarse_le;
  opts.coarse.view_head = tc.coarse_view_head;
  double want = 0;
  {
    torch::NoGradGuard no_grad;
    const auto out = model->forward(batch.rays, 2.0, 6.0, opts);
    want = (0.3 * (out.rgb_coarse - batch.target).pow(2).mean() + (out.rgb_fine - batch.target).pow(2).mean())
               .item<double>();
  }
  for (auto& p : model->parameters()) p.mutable_grad() = torch::Tensor();
  const StepSums s = accumulate_gradients(model, batch, n, tc, n, 2.0, 6.0);
  EXPECT_NEAR(s.loss.item<double>(), want, 1e-12);
  for (const auto& item : model->named_parameters()) {
    bool skipped = false;
    for (const auto& prefix : untrained) skipped = skipped || item.key().rfind(prefix, 0) == 0;
    EXPECT_EQ(item.value().grad().defined(), !skipped) << item.key();
  }
}

// train.coarse_le = false: the coarse LE transformer and its colour head get no gradient from a
// step, the other parameters do, and the loss is the one written out with the coarse colour from
// the ray token alone.
TEST(GradAccumulation, ACoarseColourWithoutItsLELeavesTheCoarseLEOut) {
  AbleNerf model = double_model(10);
  TrainConfig tc;
  tc.coarse_le = false;
  expect_coarse_variant_step(model, tc, {"le_coarse.", "le_head_coarse."});
}

// train.coarse_view_head: the coarse LE transformer gets no gradient, the coarse LE colour head
// does, and the loss is the one written out with the forward's coarse colour.
TEST(GradAccumulation, ACoarseViewHeadTrainsTheHeadWithoutTheCoarseLE) {
  AbleNerf model = double_model(11);
  TrainConfig tc;
  tc.coarse_le = false;
  tc.coarse_view_head = true;
  expect_coarse_variant_step(model, tc, {"le_coarse."});
}

TEST(GradAccumulation, SplitAndMicroBatchedGradientsEqualOneBackward) {
  const test::IntraOpThreads threads(2);  // make the ray split happen on any machine
  torch::manual_seed(8);
  AbleNerf model(test::two_head_model());
  model->to(torch::kDouble);
  model->train();
  TrainConfig tc;
  tc.coarse_weight = 0.3;  // unequal weights: a swapped coarse/fine term would show
  tc.fine_weight = 1.0;
  const int64_t n = 48;
  const RayBatch batch = some_batch(n);
  double ref_loss = 0;
  const auto ref = reference_gradients(model, batch, tc, &ref_loss);

  bool split_ran = false;
  for (const CpuSplit mode : {CpuSplit::Ops, CpuSplit::Rays}) {
    for (const int64_t micro : {n, int64_t{16}, int64_t{20}}) {
      Compute compute;
      compute.cpu_split = mode;
      model->set_compute(compute);
      if (model->cpu_ray_workers(micro, false) > 1) split_ran = true;
      for (auto& p : model->parameters()) p.mutable_grad() = torch::Tensor();
      const StepSums s = accumulate_gradients(model, batch, micro, tc, n, 2.0, 6.0);
      EXPECT_NEAR(s.loss.item<double>(), ref_loss, 1e-12) << micro;
      expect_gradients_equal(
          model, ref, "micro-batch " + std::to_string(micro) + ", split " + std::to_string(mode == CpuSplit::Rays));
    }
  }
  if (blas_thread_control_available()) {
    EXPECT_TRUE(split_ran);
  }
  // The reference gradients are not trivially zero.
  double total = 0;
  for (const auto& g : ref) total += g.abs().sum().item<double>();
  EXPECT_GT(total, 1e-6);
}

TEST(GradAccumulation, NearGradientDistanceFollowsTheNearPlane) {
  // The distance: the larger of the fixed one and the multiple of the near plane, hand-computed.
  TrainConfig tc;
  EXPECT_EQ(near_gradient_distance_for(tc, 0.3), 0.0);
  tc.near_gradient_near_multiple = 2.0;
  EXPECT_DOUBLE_EQ(near_gradient_distance_for(tc, 0.3), 0.6);
  tc.near_gradient_distance = 1.0;
  EXPECT_DOUBLE_EQ(near_gradient_distance_for(tc, 0.3), 1.0);
  EXPECT_DOUBLE_EQ(near_gradient_distance_for(tc, 0.8), 1.6);

  // The step uses it: a multiple of 1.5 at near 2 gives the gradients of a fixed distance of 3,
  // which differ from the unscaled ones (samples lie in [2, 6], so the ones before 3 are scaled).
  torch::manual_seed(8);
  AbleNerf model(test::two_head_model());
  model->to(torch::kDouble);
  model->train();
  const int64_t n = 24;
  const RayBatch batch = some_batch(n);
  const auto step = [&](double distance, double multiple) {
    TrainConfig c;
    c.near_gradient_distance = distance;
    c.near_gradient_near_multiple = multiple;
    for (auto& p : model->parameters()) p.mutable_grad() = torch::Tensor();
    accumulate_gradients(model, batch, n, c, n, 2.0, 6.0);
    std::vector<torch::Tensor> g;
    for (auto& p : model->parameters()) g.push_back(p.grad().defined() ? p.grad().clone() : torch::Tensor());
    return g;
  };
  const auto relative = step(0.0, 1.5), fixed = step(3.0, 0.0), plain = step(0.0, 0.0);
  double moved = 0;
  for (size_t i = 0; i < relative.size(); ++i) {
    if (!relative[i].defined()) continue;
    EXPECT_TRUE(torch::equal(relative[i], fixed[i])) << "parameter " << i;
    moved += (relative[i] - plain[i]).abs().max().item<double>();
  }
  EXPECT_GT(moved, 1e-9);
}

TEST(GradAccumulation, JitteredStepDoesNotDependOnTheRaySplit) {
  // model.randomized: the micro-batch's jitter is drawn once, before the split, from the global
  // stream (coarse, then fine), exactly as one forward over the whole batch draws it. Draws made
  // per thread would differ from the reference (and from run to run).
  const test::IntraOpThreads threads(2);
  auto cfg = test::two_head_model();
  cfg.randomized = true;
  torch::manual_seed(8);
  AbleNerf model(cfg);
  model->to(torch::kDouble);
  model->train();
  TrainConfig tc;
  const int64_t n = 48;
  const RayBatch batch = some_batch(n);
  double ref_loss = 0;
  torch::manual_seed(123);
  const auto ref = reference_gradients(model, batch, tc, &ref_loss);
  for (const CpuSplit mode : {CpuSplit::Ops, CpuSplit::Rays}) {
    Compute compute;
    compute.cpu_split = mode;
    model->set_compute(compute);
    for (auto& p : model->parameters()) p.mutable_grad() = torch::Tensor();
    torch::manual_seed(123);
    const StepSums s = accumulate_gradients(model, batch, n, tc, n, 2.0, 6.0);
    EXPECT_NEAR(s.loss.item<double>(), ref_loss, 1e-12);
    expect_gradients_equal(model, ref, "split " + std::to_string(mode == CpuSplit::Rays));
  }
  // The jitter is live: another stream gives another loss.
  for (auto& p : model->parameters()) p.mutable_grad() = torch::Tensor();
  torch::manual_seed(124);
  EXPECT_GT(std::abs(accumulate_gradients(model, batch, n, tc, n, 2.0, 6.0).loss.item<double>() - ref_loss), 1e-9);
}

TEST(GradAccumulation, ReportedFineMseIsTheBatchMse) {
  torch::manual_seed(9);
  AbleNerf model(test::two_head_model());
  model->to(torch::kDouble);
  TrainConfig tc;
  const RayBatch batch = some_batch(24);
  const StepSums s = accumulate_gradients(model, batch, 10, tc, 24, 2.0, 6.0);
  torch::NoGradGuard no_grad;
  model->eval();  // no jitter in either mode (model.randomized is off)
  const auto out = model->forward(batch.rays, 2.0, 6.0);
  EXPECT_NEAR(s.mse_fine.item<double>(), (out.rgb_fine - batch.target).pow(2).mean().item<double>(), 1e-12);
}

}  // namespace
}  // namespace ablenerf

namespace ablenerf {
namespace {

// Per-photo colour (model/photo_colour.h): the loss compares (I + A_p) rgb + b_p with the target,
// [A_p | b_p] the photo's parameters minus their mean, written out here with einsum; the ray split
// and micro-batches give the reference's gradients, which sum to zero over the photos, and the decay
// adds exactly 2 x decay x share / photos x delta.
TEST(GradAccumulation, PhotoColourGradientsEqualTheWrittenOutLoss) {
  const test::IntraOpThreads threads(2);
  torch::manual_seed(9);
  AbleNerf model(test::two_head_model());
  model->enable_photo_colour(4);
  model->to(torch::kDouble);
  model->train();
  {
    torch::NoGradGuard no_grad;
    model->photo_colour()->parameter().copy_(torch::randn({4, 3, 4}, torch::kDouble) * 0.1);
  }
  TrainConfig tc;
  tc.coarse_weight = 0.3;
  tc.photo_colour_decay = 0;
  const int64_t n = 48;
  RayBatch batch = some_batch(n);
  batch.photo = (torch::arange(n) % 2) * 2;  // photos 0 and 2 only

  for (auto& p : model->parameters()) p.mutable_grad() = torch::Tensor();
  const auto out = model->forward(batch.rays, 2.0, 6.0);
  const auto all = model->photo_colour()->parameter();
  const auto d = (all - all.mean(0, true)).index_select(0, batch.photo);
  const auto map = [&](const torch::Tensor& rgb) {
    const auto eye = torch::eye(3, torch::TensorOptions().dtype(torch::kDouble));
    return torch::einsum("bij,bj->bi", {d.slice(2, 0, 3) + eye, rgb.to(torch::kDouble)}) + d.select(2, 3);
  };
  const auto ref_loss_t = tc.coarse_weight * (map(out.rgb_coarse) - batch.target).pow(2).mean() +
                          tc.fine_weight * (map(out.rgb_fine) - batch.target).pow(2).mean();
  ref_loss_t.backward();
  std::vector<torch::Tensor> ref;
  for (auto& p : model->parameters()) ref.push_back(p.grad().clone());

  for (const int64_t micro : {n, int64_t{16}}) {
    for (auto& p : model->parameters()) p.mutable_grad() = torch::Tensor();
    const StepSums s = accumulate_gradients(model, batch, micro, tc, n, 2.0, 6.0);
    EXPECT_NEAR(s.loss.item<double>(), ref_loss_t.item<double>(), 1e-12) << micro;
    expect_gradients_equal(model, ref, "photo colour, micro-batch " + std::to_string(micro));
  }
  const auto g = model->photo_colour()->parameter().grad();
  EXPECT_GT(g[0].abs().sum().item<double>(), 1e-6);
  EXPECT_GT(g[2].abs().sum().item<double>(), 1e-6);
  // The maps are applied centred, so a common change of them all changes no colour: the data
  // gradients sum to zero over the photos, and the photos not drawn share one gradient.
  EXPECT_LT(g.sum(0).abs().max().item<double>(), 1e-12);
  EXPECT_LT((g[1] - g[3]).abs().max().item<double>(), 1e-15);

  tc.photo_colour_decay = 0.5;
  for (auto& p : model->parameters()) p.mutable_grad() = torch::Tensor();
  const StepSums s = accumulate_gradients(model, batch, n, tc, n, 2.0, 6.0);
  const auto delta = model->photo_colour()->parameter();
  EXPECT_NEAR(s.loss.item<double>(), ref_loss_t.item<double>() + 0.5 / 4 * delta.pow(2).sum().item<double>(), 1e-12);
  EXPECT_TRUE(torch::allclose(model->photo_colour()->parameter().grad(), g + 2 * 0.5 / 4 * delta, 0, 1e-12));
}

// Camera refinement (model/camera_refine.h): the step's rays go through their photos' corrected
// cameras before the model, so the gradients equal one backward of the loss over the corrected
// rays, on the ray split and in micro-batches; with the grid front end the corrections' gradient
// comes through the grid's lookup (the positions' gradient, kernels/hash_grid.h) as well; a photo
// with no ray in the step shares the others' (the corrections are centred), and the decay adds
// 2 x decay x share / photos x lr_scale^2 x the parameter.
TEST(GradAccumulation, CameraRefineGradientsEqualOneBackwardOverTheCorrectedRays) {
  const test::IntraOpThreads threads(2);
  for (const bool grid : {false, true}) {
    torch::manual_seed(10);
    // The grid's cube reaches 6 so that the test rays' samples fall inside it.
    const ModelConfig mc = grid ? test::two_head_grid_model(3, 8, 4, 16, 6.0) : test::two_head_model();
    AbleNerf model(mc);
    model->enable_camera_refine(4);
    const auto dtype = grid ? torch::kFloat : torch::kDouble;
    model->to(dtype);
    model->train();
    {
      torch::NoGradGuard no_grad;
      model->camera_refine()->parameter().copy_(torch::randn({4, 6}, dtype) * 0.5);
    }
    TrainConfig tc;
    tc.coarse_weight = 0.3;
    tc.camera_refine_decay = 0;
    const int64_t n = 48;
    RayBatch batch = some_batch(n);
    batch.rays = batch.rays.to(torch::kCPU);
    batch.photo = (torch::arange(n) % 2) * 2;  // photos 0 and 2 only
    const std::string what = grid ? "grid" : "ipe";

    for (auto& p : model->parameters()) p.mutable_grad() = torch::Tensor();
    const auto out = model->forward(model->camera_refine()->forward(batch.rays, batch.photo), 2.0, 6.0);
    const auto ref_loss = tc.coarse_weight * (out.rgb_coarse.to(torch::kDouble) - batch.target).pow(2).mean() +
                          tc.fine_weight * (out.rgb_fine.to(torch::kDouble) - batch.target).pow(2).mean();
    ref_loss.backward();
    const auto ref = model->camera_refine()->parameter().grad().clone();
    EXPECT_GT(ref[0].abs().max().item<double>(), 1e-5) << what;
    EXPECT_GT(ref[2].abs().max().item<double>(), 1e-5) << what;

    const double tol = grid ? 1e-4 : 1e-12;
    for (const int64_t micro : {n, int64_t{16}}) {
      for (auto& p : model->parameters()) p.mutable_grad() = torch::Tensor();
      const StepSums s = accumulate_gradients(model, batch, micro, tc, n, 2.0, 6.0);
      EXPECT_NEAR(s.loss.item<double>(), ref_loss.item<double>(), tol * ref_loss.item<double>()) << what << micro;
      const auto g = model->camera_refine()->parameter().grad();
      EXPECT_LT((g - ref).abs().max().item<double>(), tol * ref.abs().max().item<double>()) << what << micro;
      // Centred corrections: the gradients sum to zero over the photos, and the photos with no ray
      // in the step (1 and 3) share one.
      EXPECT_LT(g.sum(0).abs().max().item<double>(), tol * ref.abs().max().item<double>()) << what;
      EXPECT_TRUE(torch::equal(g[1], g[3])) << what;
    }
    tc.camera_refine_decay = 0.5;
    for (auto& p : model->parameters()) p.mutable_grad() = torch::Tensor();
    accumulate_gradients(model, batch, n, tc, n, 2.0, 6.0);
    // On the corrections, lr_scale x the parameter: d/dparam = 2 x 0.5 / 4 x lr_scale^2 x param.
    const auto& p = model->camera_refine()->parameter();
    const double k = model->camera_refine()->lr_scale();
    EXPECT_TRUE(torch::allclose(p.grad() - ref, 2 * 0.5 / 4 * k * k * p, 0, grid ? 1e-6 : 1e-12)) << what;
  }
}

// The grid tables' gradients (the front end's and the proposal field's) deferred by the
// step's threads (kernels/table_gradient.h), with the front end's decay added in the same pass, equal
// autograd's through one backward of the same loss plus the decay's own gradient
// (add_grid_weight_decay), on the ray split and in micro-batches; nothing is left deferred
// afterwards. Left to Adam's update (tables_in_update), the tables get no .grad, their lookups stay
// deferred and their decay is not in the loss yet.
TEST(GradAccumulation, GridTablesGatheredInSlotsEqualOneBackward) {
  const test::IntraOpThreads threads(2);
  torch::manual_seed(12);
  ModelConfig mc = test::two_head_grid_model(3, 8, 4, 16, 6.0);
  mc.proposal_samples = 8;
  mc.proposal_levels = 2;
  mc.proposal_log2_table = 7;
  mc.proposal_max_resolution = 8;
  AbleNerf model(mc);
  model->train();
  TrainConfig tc;
  tc.coarse_weight = 0.3;
  tc.grid_decay = 0.5;
  tc.proposal_weight = 1.0;
  const int64_t n = 48;
  RayBatch batch = some_batch(n);
  GridEmbeddingImpl& front = *model->grid();
  GridEmbeddingImpl& proposal = model->proposal()->grid();
  const auto front_table = front.table_parameter(), proposal_table = proposal.table_parameter();

  for (auto& p : model->parameters()) p.mutable_grad() = torch::Tensor();
  const LossTerms t = ray_loss(model->forward(batch.rays, 2.0, 6.0), batch.target, tc, n);
  t.loss.backward();
  // The decay over the entries a lookup reaches (a dense level's unused rows take none: the
  // finishing pass leaves them at 0).
  const auto front_mask = test::table_entries_mask(front), proposal_mask = test::table_entries_mask(proposal);
  const double coefficient = grid_decay_coefficient(front_table, front.lr_scale(), tc.grid_decay);
  const auto decay = (front_table.detach() * front_mask).pow(2).sum() * coefficient;
  const auto ref_front = front_table.grad() * front_mask + front_table.detach() * front_mask * (2 * coefficient);
  const auto ref_proposal = proposal_table.grad() * proposal_mask;
  ASSERT_LT(front_mask.mean().item<double>(), 1.0) << "the test's front end has no dense level with unused rows";
  EXPECT_GT(ref_proposal.abs().sum().item<double>(), 1e-6) << "the proposal's table got no gradient";

  for (const int64_t micro : {n, int64_t{16}}) {
    for (auto& p : model->parameters()) p.mutable_grad() = torch::Tensor();
    const StepSums s = accumulate_gradients(model, batch, micro, tc, n, 2.0, 6.0);
    EXPECT_NEAR(s.terms[kTermGridDecay].item<double>(), decay.item<double>(), 1e-6 * decay.item<double>());
    EXPECT_NEAR(s.loss.item<double>(), (t.loss + decay).item<double>(), 1e-5 * s.loss.item<double>());
    for (const auto& [got, want, name] : {std::make_tuple(front_table.grad(), ref_front, "front end"),
                                          std::make_tuple(proposal_table.grad(), ref_proposal, "proposal")}) {
      ASSERT_TRUE(got.defined()) << name;
      EXPECT_LT((got - want).abs().max().item<double>(), 1e-5 * (1e-3 + want.abs().max().item<double>()))
          << name << ", micro-batch " << micro;
    }
    EXPECT_FALSE(front.table_gradient().pending());
    EXPECT_FALSE(proposal.table_gradient().pending());
    // Both tables' gradients were found finite in the pass that gathered them.
    ASSERT_EQ(s.finite_tables.size(), 2u);
    for (const auto& table : {front_table, proposal_table})
      EXPECT_TRUE(s.finite_tables[0].is_same(table) || s.finite_tables[1].is_same(table));
  }
  for (auto& p : model->parameters()) p.mutable_grad() = torch::Tensor();
  const StepSums s = accumulate_gradients(model, batch, 16, tc, n, 2.0, 6.0, {}, /*tables_in_update=*/true);
  EXPECT_NEAR(s.loss.item<double>(), t.loss.item<double>(), 1e-5 * s.loss.item<double>());
  EXPECT_EQ(s.terms[kTermGridDecay].item<double>(), 0.0);
  EXPECT_TRUE(s.finite_tables.empty());
  ASSERT_EQ(s.tables.size(), 2u);
  for (const auto& step : s.tables) {
    const bool is_front = step.param.is_same(front_table);
    EXPECT_TRUE(is_front || step.param.is_same(proposal_table));
    EXPECT_EQ(step.decay, is_front ? coefficient : 0.0);
    EXPECT_FALSE(step.param.grad().defined());
    EXPECT_TRUE(step.gradient->pending());
    step.gradient->discard();
  }
}

}  // namespace
}  // namespace ablenerf
