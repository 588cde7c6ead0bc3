// The host form of the training step's Adam (train/adam.h) against torch::optim::Adam, the plain
// LibTorch reference: with CPU float32 parameters it runs its own loops, which must follow the
// reference step for step (moments, per-parameter step counts, parameters that get no gradient on
// some steps, a learning-rate change) and skip non-finite steps without touching anything.
#include <gtest/gtest.h>
#include <torch/torch.h>
#include <torch/version.h>

#include <cmath>
#include <limits>
#include <sstream>
#include <utility>
#include <vector>

#include "kernels/cpu_parallel.h"
#include "kernels/hash_grid.h"
#include "kernels/table_gradient.h"
#include "test_util.h"
#include "train/adam.h"

using namespace ablenerf;

namespace {

std::vector<torch::Tensor> make_params(torch::Dtype dtype) {
  torch::manual_seed(21);
  std::vector<torch::Tensor> p;
  // The last is a small grid table's size: large enough for the loops to be split over threads.
  for (const auto& shape : std::vector<std::vector<int64_t>>{{7, 5}, {5}, {3, 4, 2}, {1}, {3, 50000, 2}})
    p.push_back(torch::randn(shape, torch::TensorOptions().dtype(dtype)).requires_grad_(true));
  return p;
}

std::vector<torch::Tensor> clone_params(const std::vector<torch::Tensor>& ps) {
  std::vector<torch::Tensor> out;
  for (const auto& p : ps) out.push_back(p.detach().clone().requires_grad_(true));
  return out;
}

// Gradients of step `s`: parameter 2 gets none on odd steps (its state must not advance then).
void set_grads(std::vector<torch::Tensor>& ps, int s) {
  auto gen = at::detail::createCPUGenerator(100 + s);
  for (size_t i = 0; i < ps.size(); ++i) {
    if (i == 2 && s % 2 == 1) {
      ps[i].mutable_grad() = torch::Tensor();
      continue;
    }
    // Scales over several decades, so that eps and the bias corrections matter.
    ps[i].mutable_grad() =
        torch::randn(ps[i].sizes(), gen).to(ps[i].scalar_type()) * std::pow(10.0, -double(i) - s % 3);
  }
}

}  // namespace

TEST(Adam, HostLoopsOnlyForCpuFloat32) {
  EXPECT_TRUE(Adam(make_params(torch::kFloat), 1e-3, false).host_loops());
  EXPECT_FALSE(Adam(make_params(torch::kDouble), 1e-3, false).host_loops());
}

namespace {

// Twelve steps of the host loops and of torch::optim::Adam with the same constants.
void follow_reference(const AdamSettings& settings) {
  auto mine = make_params(torch::kFloat);
  auto ref = clone_params(mine);
  Adam adam(mine, 2e-3, false, settings);
  ASSERT_TRUE(adam.host_loops());
  torch::optim::Adam reference(
      ref, torch::optim::AdamOptions(2e-3).betas({settings.beta1, settings.beta2}).eps(settings.eps));
  for (int s = 0; s < 12; ++s) {
    if (s == 6) {
      adam.set_lr(5e-4);
      static_cast<torch::optim::AdamOptions&>(reference.param_groups().front().options()).lr(5e-4);
    }
    set_grads(mine, s);
    set_grads(ref, s);
    ASSERT_TRUE(adam.step_host(1.0));
    reference.step();
    for (size_t i = 0; i < mine.size(); ++i)
      ASSERT_TRUE(torch::allclose(mine[i], ref[i], 1e-5, 1e-7)) << "parameter " << i << " after step " << s;
  }
  // The state lives where checkpoints read it: per-parameter moments and step counts.
  for (size_t i = 0; i < mine.size(); ++i) {
    // The optimiser's state is keyed by the parameter's TensorImpl: its address as text in
    // LibTorch 1.x, the pointer itself from 2.0.
#if TORCH_VERSION_MAJOR >= 2
    const auto key = [](const torch::Tensor& p) { return static_cast<void*>(p.unsafeGetTensorImpl()); };
#else
    const auto key = [](const torch::Tensor& p) {
      std::ostringstream os;
      os << p.unsafeGetTensorImpl();
      return os.str();
    };
#endif
    auto& a = static_cast<torch::optim::AdamParamState&>(*adam.optim().state().at(key(mine[i])));
    auto& b = static_cast<torch::optim::AdamParamState&>(*reference.state().at(key(ref[i])));
    EXPECT_EQ(a.step(), b.step()) << "parameter " << i;
    // Absolute slack of about one float32 ulp of the smallest gradients' moments (1e-5): where
    // beta1 m and (1 - beta1) g cancel, LibTorch's vectorised fused update and the loop round apart.
    EXPECT_TRUE(torch::allclose(a.exp_avg(), b.exp_avg(), 1e-5, 1e-11)) << "parameter " << i;
    EXPECT_TRUE(torch::allclose(a.exp_avg_sq(), b.exp_avg_sq(), 1e-5, 1e-20)) << "parameter " << i;
  }
}

}  // namespace

TEST(Adam, HostLoopsFollowTorchOptimAdam) { follow_reference(AdamSettings{}); }

// Other constants (instant-ngp's beta2 0.99, a larger eps) reach the loops' arithmetic.
TEST(Adam, HostLoopsFollowTorchOptimAdamWithOtherConstants) { follow_reference(AdamSettings{0.8, 0.99, 1e-6}); }

// A loaded checkpoint brings the options it was saved with; the run's own settings win.
TEST(Adam, ThreadCountChangesNoBit) {
  // The update is element by element: one thread or several give the same parameters and moments.
  // The loops split by cpu_workers, whose budget is the larger of LibTorch's and OpenBLAS's thread
  // counts: the serial run holds both to one, and each run checks how many workers it had.
  int64_t total = 0;
  for (const auto& p : make_params(torch::kFloat)) total += p.numel();
  const auto run = [total](int threads, int64_t* workers) {
    const test::IntraOpThreads scope(threads);  // 1: OpenBLAS's pool held to one thread too
    *workers = cpu_workers(total, int64_t{1} << 16);
    auto ps = make_params(torch::kFloat);
    Adam adam(ps, 2e-3, false);
    for (int s = 0; s < 4; ++s) {
      set_grads(ps, s);
      EXPECT_TRUE(adam.step_host(1.0));
    }
    return ps;
  };
  int64_t serial = 0, split = 0;
  const auto one = run(1, &serial), two = run(2, &split);
  EXPECT_EQ(serial, 1);
  for (size_t i = 0; i < one.size(); ++i) EXPECT_TRUE(torch::equal(one[i], two[i])) << "parameter " << i;
  if (split < 2) GTEST_SKIP() << "one worker with two threads asked for: no OpenBLAS thread control in this build";
}

// With a parameter's entries set, its update touches only those: the same values there as the
// update of the whole parameter, the rest of it and of its moments untouched.
TEST(Adam, EntriesSetKeepTheOthersAsTheyAre) {
  auto whole = make_params(torch::kFloat);
  auto part = clone_params(whole);
  Adam a(whole, 1e-2, false), b(part, 1e-2, false);
  const IndexRanges entries{{0, 1000}, {150000, 250000}, {299990, 300000}};
  b.set_entries(part[4], entries);
  const auto start = part[4].detach().clone();
  for (int s = 0; s < 3; ++s) {
    set_grads(whole, s);
    for (size_t i = 0; i < whole.size(); ++i)
      part[i].mutable_grad() = whole[i].grad().defined() ? whole[i].grad().clone() : torch::Tensor();
    ASSERT_TRUE(a.step_host(1.0));
    ASSERT_TRUE(b.step_host(1.0));
  }
  const auto inside = torch::zeros({300000}, torch::kBool);
  for (const auto& r : entries) inside.slice(0, r.first, r.second).fill_(true);
  const auto flat_whole = whole[4].detach().reshape({-1}), flat_part = part[4].detach().reshape({-1});
  EXPECT_TRUE(torch::equal(flat_part.masked_select(inside), flat_whole.masked_select(inside)));
  EXPECT_TRUE(torch::equal(flat_part.masked_select(~inside), start.reshape({-1}).masked_select(~inside)));
  for (size_t i = 0; i < 4; ++i) EXPECT_TRUE(torch::equal(part[i], whole[i])) << i;
}

TEST(Adam, FromCheckpointRestoresTheRunsConstants) {
  auto ps = make_params(torch::kFloat);
  Adam adam(ps, 1e-3, false, AdamSettings{0.85, 0.95, 1e-7});
  auto& opts = static_cast<torch::optim::AdamOptions&>(adam.optim().param_groups().front().options());
  opts.betas({0.9, 0.999}).eps(1e-8);  // what a checkpoint of a default run would load
  adam.from_checkpoint();
  EXPECT_EQ(std::get<0>(opts.betas()), 0.85);
  EXPECT_EQ(std::get<1>(opts.betas()), 0.95);
  EXPECT_EQ(opts.eps(), 1e-7);
}

// A parameter the caller names as checked (the grid table whose gradient the gathering pass found
// finite) is not read by the finite check again, so a value planted there goes unseen, while the
// same value in a parameter not named still skips the step; the update covers both.
TEST(Adam, ParametersCheckedByTheCallerAreNotCheckedAgain) {
  auto ps = make_params(torch::kFloat);
  auto ref = clone_params(ps);
  Adam adam(ps, 1e-2, false);
  Adam plain(ref, 1e-2, false);
  set_grads(ps, 0);
  set_grads(ref, 0);
  ASSERT_TRUE(adam.step_host(1.0, {ps[4]}));
  ASSERT_TRUE(plain.step_host(1.0));
  for (size_t i = 0; i < ps.size(); ++i) EXPECT_TRUE(torch::equal(ps[i], ref[i])) << "parameter " << i;
  set_grads(ps, 1);
  ps[4].mutable_grad().view(-1)[7] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_TRUE(adam.step_host(1.0, {ps[4]}));
  EXPECT_TRUE(std::isnan(ps[4].view(-1)[7].item<float>()));
  set_grads(ps, 1);
  ps[3].mutable_grad().view(-1)[0] = std::numeric_limits<float>::quiet_NaN();
  const auto before = clone_params(ps);
  EXPECT_FALSE(adam.step_host(1.0, {ps[4]}));
  for (size_t i = 0; i < ps.size(); ++i)
    EXPECT_TRUE(torch::allclose(ps[i], before[i], 0, 0, /*equal_nan=*/true)) << "parameter " << i;
}

TEST(Adam, NonFiniteGradientOrLossSkipsTheStep) {
  for (const float bad : {std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity(),
                          -std::numeric_limits<float>::infinity()}) {
    auto ps = make_params(torch::kFloat);
    Adam adam(ps, 1e-2, false);
    set_grads(ps, 0);
    ASSERT_TRUE(adam.step_host(1.0));  // a first finite step creates the state
    const auto before = clone_params(ps);
    // Inside the checks' 8-wide lanes (parameter 2, 24 values) and in their tails (parameter 1,
    // 5 values; parameter 0, 35 values); in the table, whose 300,000 values the check splits
    // between the threads (its first, middle and last value).
    for (const auto& [param, index] :
         std::vector<std::pair<size_t, int64_t>>{{2, 5}, {1, 3}, {0, 34}, {4, 0}, {4, 150000}, {4, 299999}}) {
      set_grads(ps, 2);
      ps[param].mutable_grad().view(-1)[index] = bad;
      EXPECT_FALSE(adam.step_host(1.0)) << "parameter " << param << " value " << index;
      for (size_t i = 0; i < ps.size(); ++i) EXPECT_TRUE(torch::equal(ps[i], before[i])) << "parameter " << i;
    }
    set_grads(ps, 2);
    EXPECT_FALSE(adam.step_host(std::numeric_limits<double>::quiet_NaN()));
    for (size_t i = 0; i < ps.size(); ++i) EXPECT_TRUE(torch::equal(ps[i], before[i])) << "parameter " << i;
    // The next finite step is the second step of every state (the skipped ones did not count).
    EXPECT_TRUE(adam.step_host(1.0));
    for (const auto& kv : adam.optim().state())
      EXPECT_EQ(static_cast<torch::optim::AdamParamState&>(*kv.second).step(), 2);
  }
}

namespace {

// A small grid table (a dense level and hashed ones: hash_grid_shape) as a parameter of its own,
// and lookups deferred to its TableGradient as a training step's threads would.
struct TableFixture {
  HashGridShape shape = hash_grid_shape(4, 2, 9, 4, 64);
  torch::Tensor table;
  TableGradient gradient{shape};
  explicit TableFixture(uint64_t seed) {
    auto gen = at::detail::createCPUGenerator(seed);
    table = (torch::randn({shape.levels, shape.table_size, shape.features}, gen) * 1e-2).requires_grad_(true);
  }
  DeferredLookup lookup(int step, int64_t n = 400) const {
    auto gen = at::detail::createCPUGenerator(500 + step);
    return {torch::rand({n, 3}, gen), torch::randn({n, shape.levels, shape.features}, gen) * 1e-2, {}};
  }
};

}  // namespace

// A table whose gradient is formed inside the update (Adam::TableStep) follows the same steps, to
// the bit, as the same table given its gradient in .grad by TableGradient::finish (the decay's term
// included) and updated with the other parameters over the entries a lookup reaches; its decay's
// value comes back; its state counts steps as a .grad parameter's would.
TEST(Adam, ATableUpdatedFromItsLookupsFollowsTheGradientPath) {
  auto ps = make_params(torch::kFloat);
  auto ref = clone_params(ps);
  TableFixture t(3), r(3);
  ps.push_back(t.table);
  ref.push_back(r.table);
  Adam adam(ps, 1e-2, false);
  Adam plain(ref, 1e-2, false);
  plain.set_entries(r.table, hash_grid_table_entries(r.shape));
  const double decay = 0.05;
  for (int s = 0; s < 4; ++s) {
    set_grads(ps, s);
    set_grads(ref, s);
    ps.back().mutable_grad() = torch::Tensor();
    ref.back().mutable_grad() = torch::Tensor();
    t.gradient.defer(0, t.lookup(s));
    r.gradient.defer(0, r.lookup(s));
    const double want = r.gradient.finish(ref.back(), decay);
    std::vector<Adam::TableStep> tables{{t.table, &t.gradient, decay}};
    ASSERT_TRUE(adam.step_host(1.0, {}, &tables));
    ASSERT_TRUE(plain.step_host(1.0));
    EXPECT_NEAR(tables[0].value, want, 1e-12 * want);
    EXPECT_FALSE(t.gradient.pending());
    for (size_t i = 0; i < ps.size(); ++i)
      EXPECT_TRUE(torch::equal(ps[i], ref[i])) << "parameter " << i << " step " << s;
  }
  EXPECT_GT((t.table - TableFixture(3).table).abs().max().item<double>(), 1e-3);
  for (const auto& kv : adam.optim().state())
    EXPECT_GE(static_cast<torch::optim::AdamParamState&>(*kv.second).step(), 2);
  // Nothing deferred and no decay: no gradient, so no step (the state stays where it was).
  std::vector<Adam::TableStep> idle{{t.table, &t.gradient, 0.0}};
  const auto table_before = t.table.detach().clone();
  set_grads(ps, 0);
  ps.back().mutable_grad() = torch::Tensor();
  ASSERT_TRUE(adam.step_host(1.0, {}, &idle));
  EXPECT_TRUE(torch::equal(t.table, table_before));
  EXPECT_EQ(idle[0].value, 0.0);
}

// A step whose loss, other gradients or the table's lookups are not finite is skipped whole: no
// parameter moves, the table's lookups are dropped, and the next step counts as the second.
TEST(Adam, ANonFiniteStepLeavesTheTableAndDropsItsLookups) {
  for (int kind = 0; kind < 3; ++kind) {
    auto ps = make_params(torch::kFloat);
    TableFixture t(4);
    ps.push_back(t.table);
    Adam adam(ps, 1e-2, false);
    set_grads(ps, 0);
    ps.back().mutable_grad() = torch::Tensor();
    t.gradient.defer(0, t.lookup(0));
    std::vector<Adam::TableStep> tables{{t.table, &t.gradient, 0.05}};
    ASSERT_TRUE(adam.step_host(1.0, {}, &tables));
    const auto before = clone_params(ps);
    set_grads(ps, 1);
    ps.back().mutable_grad() = torch::Tensor();
    auto bad = t.lookup(1);
    if (kind == 0) bad.grad_out.view(-1)[123] = std::numeric_limits<float>::quiet_NaN();
    if (kind == 1) ps[1].mutable_grad().view(-1)[2] = std::numeric_limits<float>::infinity();
    t.gradient.defer(0, bad);
    EXPECT_FALSE(adam.step_host(kind == 2 ? std::numeric_limits<double>::quiet_NaN() : 1.0, {}, &tables))
        << "kind " << kind;
    EXPECT_FALSE(t.gradient.pending()) << "kind " << kind;
    for (size_t i = 0; i < ps.size(); ++i) EXPECT_TRUE(torch::equal(ps[i], before[i])) << "parameter " << i;
    set_grads(ps, 2);
    ps.back().mutable_grad() = torch::Tensor();
    t.gradient.defer(0, t.lookup(2));
    EXPECT_TRUE(adam.step_host(1.0, {}, &tables));
    for (const auto& kv : adam.optim().state())
      EXPECT_EQ(static_cast<torch::optim::AdamParamState&>(*kv.second).step(), 2) << "kind " << kind;
  }
}
