// A hash grid table's gradient from deferred lookups (kernels/table_gradient.h): finish() against
// its LibTorch reference (the plain lookup differentiated by autograd, the decay's closed form) on a
// table with a dense level and hashed ones, in every instruction form, with and without a gradient
// before; the entries no lookup reaches left at 0; infinities and NaNs found; the same bits whatever
// order the threads deferred in and on any number of threads; lookups with a key open defer exactly
// the gradient autograd gives the plain lookup, from two threads at once, while autograd gets none
// for the table and still gives the positions theirs; without a key (or gradient mode) nothing is
// deferred.
#include <gtest/gtest.h>

#include <limits>
#include <thread>

#include "kernels/adam_cpu.h"
#include "kernels/cpu_parallel.h"
#include "kernels/hash_grid.h"
#include "kernels/kernel_test_util.h"
#include "kernels/table_gradient.h"

namespace ablenerf {
namespace {

// Level 0 dense (5^3 = 125 of 128 rows reached), levels 1-3 hashed.
HashGridShape small_shape(int features = 2) { return hash_grid_shape(4, features, 7, 4, 32); }

// n points of the unit cube (some on its faces and outside it), their features' gradient, and
// scales for some lookups.
DeferredLookup some_lookup(const HashGridShape& s, int64_t n, uint64_t seed, bool scaled) {
  auto gen = at::detail::createCPUGenerator(seed);
  auto positions = torch::rand({n, 3}, gen) * 1.2 - 0.1;
  const auto grad_out = test::seeded_randn({n, s.levels, s.features}, seed + 1).to(torch::kFloat);
  const auto scales = scaled ? torch::rand({n, s.levels}, gen) : torch::Tensor();
  return {positions.contiguous(), grad_out, scales};
}

torch::Tensor table_of(const HashGridShape& s, uint64_t seed) {
  return test::seeded_randn({s.levels, s.table_size, s.features}, seed).to(torch::kFloat);
}

torch::Tensor reached_mask(const HashGridShape& s) {
  auto mask = torch::zeros({int64_t{s.levels} * s.table_size * s.features});
  for (const auto& [begin, end] : hash_grid_table_entries(s)) mask.slice(0, begin, end).fill_(1);
  return mask.view({s.levels, s.table_size, s.features});
}

// Three lookups deferred under keys 2, 0, 1 (finish() sums them in key order), the middle one scaled.
std::vector<DeferredLookup> defer_three(TableGradient& tg, const HashGridShape& s, int64_t n) {
  std::vector<DeferredLookup> in_key_order(3);
  for (const int k : {2, 0, 1}) {
    in_key_order[static_cast<size_t>(k)] = some_lookup(s, n + k, 40 + static_cast<uint64_t>(k), k == 1);
    tg.defer(k, in_key_order[static_cast<size_t>(k)]);
  }
  return in_key_order;
}

TEST(TableGradient, FinishAddsTheLookupsAndTheDecayAsTheReference) {
  for (const int features : {2, 3}) {  // the presets' width (its own vector loops) and another
    const HashGridShape s = small_shape(features);
    const auto param = table_of(s, 1);
    const auto mask = reached_mask(s);
    ASSERT_LT(mask.mean().item<double>(), 1.0);
    for (const CpuVectorForm form : {CpuVectorForm::Scalar, CpuVectorForm::Avx512}) {
      if (!cpu_vector_form_available(form)) continue;
      for (const bool with_grad : {false, true}) {
        for (const double decay : {0.0, 0.125}) {
          TableGradient tg(s);
          const auto lookups = defer_three(tg, s, 37);  // 37, 38, 39 points: tails of 16-point vectors
          auto p = param.clone().set_requires_grad(true);
          const auto before = table_of(s, 7);
          if (with_grad) p.mutable_grad() = before.clone();
          EXPECT_TRUE(tg.pending());
          const double value = tg.finish(p, decay, form);
          const auto want = table_gradient_reference(with_grad ? before : torch::Tensor(), lookups, param, s, decay);
          const std::string what = "features " + std::to_string(features) + ", grad before " +
                                   std::to_string(with_grad) + ", decay " + std::to_string(decay);
          EXPECT_LT(test::max_abs(p.grad() - want), 2e-5) << what;
          EXPECT_GT(test::max_abs(want - (with_grad ? before : torch::zeros_like(before))), 0.1) << what;
          if (!with_grad) {
            EXPECT_EQ(test::max_abs(p.grad() * (1 - mask)), 0.0) << what;
          }
          const auto squares = (with_grad ? param : param * mask).to(torch::kDouble).pow(2).sum().item<double>();
          EXPECT_NEAR(value, decay * squares, 1e-9) << what;
          EXPECT_TRUE(tg.wrote_finite_gradient());
          EXPECT_FALSE(tg.pending());
        }
      }
    }
  }
}

// The scatter adds the same products in the same order in every form, and finish() its decay term
// the same way: one gradient to the bit.
TEST(TableGradient, EveryFormWritesTheSameBits) {
  if (!cpu_vector_form_available(CpuVectorForm::Avx512)) GTEST_SKIP() << "no AVX-512 on this CPU";
  const HashGridShape s = small_shape();
  torch::Tensor got[2];
  int i = 0;
  for (const CpuVectorForm form : {CpuVectorForm::Scalar, CpuVectorForm::Avx512}) {
    TableGradient tg(s);
    defer_three(tg, s, 200);
    auto p = table_of(s, 2).set_requires_grad(true);
    tg.finish(p, 0.25, form);
    got[i++] = p.grad().clone();
  }
  EXPECT_TRUE(torch::equal(got[0], got[1]));
}

// Keys decide the order of the sums, not the order the lookups came in; and the levels' sharing
// among threads changes nothing (a table large enough for two: 4 x 2^15 rows of 2 floats).
TEST(TableGradient, TheSameBitsWhateverOrderTheLookupsCameIn) {
  const HashGridShape s = hash_grid_shape(4, 2, 15, 16, 256);
  const auto a = some_lookup(s, 300, 3, false), b = some_lookup(s, 301, 5, true);
  const auto run = [&](bool b_first) {
    TableGradient tg(s);
    if (b_first) tg.defer(1, b);
    tg.defer(0, a);
    if (!b_first) tg.defer(1, b);
    auto p = table_of(s, 2).set_requires_grad(true);
    tg.finish(p, 0.25);
    return p.grad().clone();
  };
  const int before = at::get_num_threads();
  at::set_num_threads(2);
  const int64_t workers = cpu_workers(int64_t{s.levels} * s.table_size * s.features, 1 << 16);
  const auto threads = run(false);
  EXPECT_TRUE(torch::equal(threads, run(true)));
  // Inside a worker of a split, on one thread.
  torch::Tensor serial;
  parallel_slices(2, 2, [&](int64_t w, int64_t, int64_t) {
    if (w == 1) serial = run(false);
  });
  at::set_num_threads(before);
  EXPECT_TRUE(torch::equal(threads, serial));
  if (workers < 2) GTEST_SKIP() << "the levels were not shared among threads here (no OpenBLAS thread control)";
}

// The buffer reused step after step stays 0 where no lookup reaches; a gradient already on the
// parameter makes finish() write every entry, and the entries alone again after it.
TEST(TableGradient, TheEntriesNoLookupReachesStayZero) {
  const HashGridShape s = small_shape();
  const auto param = table_of(s, 3);
  const auto mask = reached_mask(s);
  TableGradient tg(s);
  for (int step = 0; step < 2; ++step) {
    const auto lookups = defer_three(tg, s, 50 + step);
    auto p = param.clone().set_requires_grad(true);
    tg.finish(p, 0.125);
    EXPECT_LT(test::max_abs(p.grad() - table_gradient_reference({}, lookups, param, s, 0.125)), 2e-5) << step;
    EXPECT_EQ(test::max_abs(p.grad() * (1 - mask)), 0.0) << step;
  }
  const auto before = table_of(s, 31);
  const DeferredLookup one = some_lookup(s, 60, 9, false);
  tg.defer(0, one);
  auto p = param.clone().set_requires_grad(true);
  p.mutable_grad() = before.clone();
  tg.finish(p, 0.125);
  EXPECT_LT(test::max_abs(p.grad() - table_gradient_reference(before, {one}, param, s, 0.125)), 2e-5);
  EXPECT_GT(test::max_abs(p.grad() * (1 - mask)), 0.1);
  tg.defer(0, one);
  auto q = param.clone().set_requires_grad(true);
  tg.finish(q, 0.125);
  EXPECT_EQ(test::max_abs(q.grad() * (1 - mask)), 0.0);
}

// finish() says whether the gradient it wrote is finite: an infinity or NaN in a lookup's gradient
// (first point, inside the 16-point vectors, the tail) or in the gradient before is found by every
// form; a pass that wrote nothing vouches for nothing.
TEST(TableGradient, FinishFindsAnInfiniteOrNaNEntry) {
  const HashGridShape s = small_shape();
  const auto param = table_of(s, 1);
  for (const CpuVectorForm form : {CpuVectorForm::Scalar, CpuVectorForm::Avx512}) {
    if (!cpu_vector_form_available(form)) continue;
    for (const float bad : {std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity(),
                            -std::numeric_limits<float>::infinity(), 0.0f}) {
      for (const int64_t at : {int64_t(0), int64_t(17 * 8 + 3), int64_t(36 * 8 + 7)}) {  // of 37 x 4 x 2
        for (const int k : {0, 1}) {
          TableGradient tg(s);
          for (int j = 0; j < 2; ++j) {
            auto d = some_lookup(s, 37, 10 + static_cast<uint64_t>(j), false);
            if (j == k) d.grad_out.view(-1)[at] = bad;
            tg.defer(j, d);
          }
          auto p = param.clone().set_requires_grad(true);
          tg.finish(p, 0.125, form);
          EXPECT_EQ(tg.wrote_finite_gradient(), bad == 0.0f) << bad << " at " << at << " of lookup " << k;
          EXPECT_EQ(p.grad().isfinite().all().item<bool>(), bad == 0.0f);
        }
      }
      TableGradient tg(s);
      tg.defer(0, some_lookup(s, 20, 3, false));
      auto p = param.clone().set_requires_grad(true);
      auto before = torch::zeros_like(param);
      before.view(-1)[param.numel() - 1] = bad;  // an entry no lookup reaches
      p.mutable_grad() = before;
      tg.finish(p, 0.125, form);
      EXPECT_EQ(tg.wrote_finite_gradient(), bad == 0.0f) << bad << " in the gradient before";
    }
  }
  TableGradient tg(s);
  auto p = param.clone().set_requires_grad(true);
  tg.finish(p, 0.0);
  EXPECT_FALSE(tg.wrote_finite_gradient());
}

// finish_adam() updates the table and its moments exactly as finish() followed by Adam's update of
// the gradient it wrote (kernels/adam_cpu.h), to the bit, in every form, on the entries a lookup
// reaches only, and returns the same decay value; its lookups are consumed.
TEST(TableGradient, FinishAdamIsFinishThenTheUpdate) {
  const HashGridShape s = small_shape();
  const auto mask = reached_mask(s);
  const AdamScalars sc{0.9f, 0.1f, 0.999f, 0.001f, 1e-8f, 0.05f, -0.01f};
  for (const CpuVectorForm form : {CpuVectorForm::Scalar, CpuVectorForm::Avx512}) {
    if (!cpu_vector_form_available(form)) continue;
    const auto w0 = table_of(s, 4);
    const auto m0 = table_of(s, 5) * 1e-3, v0 = table_of(s, 6).abs() * 1e-4;
    // finish(), then the update over the reached entries.
    TableGradient a(s);
    defer_three(a, s, 90);
    auto pa = w0.clone().set_requires_grad(true);
    const double value_a = a.finish(pa, 0.125, form);
    auto wa = w0.clone(), ma = m0.clone(), va = v0.clone();
    for (const auto& [begin, end] : hash_grid_table_entries(s))
      adam_update_cpu_in(form, end - begin, pa.grad().data_ptr<float>() + begin, ma.data_ptr<float>() + begin,
                         va.data_ptr<float>() + begin, wa.data_ptr<float>() + begin, sc);
    // In one pass.
    TableGradient b(s);
    defer_three(b, s, 90);
    EXPECT_TRUE(b.lookups_finite());
    auto pb = w0.clone().set_requires_grad(true);
    auto mb = m0.clone(), vb = v0.clone();
    const double value_b = b.finish_adam(pb, 0.125, sc, mb.data_ptr<float>(), vb.data_ptr<float>(), form);
    EXPECT_TRUE(b.wrote_finite_gradient());
    EXPECT_FALSE(b.pending());
    EXPECT_FALSE(pb.grad().defined());
    EXPECT_TRUE(torch::equal(pb.detach(), wa));
    EXPECT_TRUE(torch::equal(mb, ma));
    EXPECT_TRUE(torch::equal(vb, va));
    EXPECT_NEAR(value_b, value_a, 1e-12 * value_a);
    EXPECT_GT(test::max_abs((pb.detach() - w0) * mask), 1e-3);
    EXPECT_EQ(test::max_abs((pb.detach() - w0) * (1 - mask)), 0.0);
    // On a parameter that holds a gradient: refused.
    defer_three(b, s, 90);
    test::expect_error_naming([&] { b.finish_adam(pa, 0.125, sc, mb.data_ptr<float>(), vb.data_ptr<float>(), form); },
                              "gradient");
  }
}

// lookups_finite(): false for an infinity or NaN in a lookup's gradient or scales, or magnitudes
// whose sum could overflow; true otherwise, and with nothing deferred.
TEST(TableGradient, LookupsFiniteLooksAtTheLookupsValues) {
  const HashGridShape s = small_shape();
  TableGradient tg(s);
  EXPECT_TRUE(tg.lookups_finite());
  defer_three(tg, s, 30);
  EXPECT_TRUE(tg.lookups_finite());
  for (int kind = 0; kind < 4; ++kind) {
    TableGradient bad(s);
    defer_three(bad, s, 30);
    auto d = some_lookup(s, 25, 8, true);
    if (kind == 0) d.grad_out.view(-1)[37] = std::numeric_limits<float>::quiet_NaN();
    if (kind == 1) d.scales.view(-1)[11] = std::numeric_limits<float>::infinity();
    if (kind == 2) d.grad_out.view(-1)[0] = 1e31f;  // finite, but a sum of such could overflow
    if (kind == 3) d.grad_out.view(-1)[99] = -std::numeric_limits<float>::infinity();
    bad.defer(1, d);
    EXPECT_FALSE(bad.lookups_finite()) << "kind " << kind;
  }
}

TEST(TableGradient, NothingDeferredAndNoDecayLeavesTheGradientAlone) {
  const HashGridShape s = small_shape();
  TableGradient tg(s);
  auto p = torch::ones({s.levels, s.table_size, s.features}).set_requires_grad(true);
  EXPECT_EQ(tg.finish(p, 0.0), 0.0);
  EXPECT_FALSE(p.grad().defined());
  // The decay alone still makes a gradient, on the entries a lookup reaches.
  const auto mask = reached_mask(s);
  EXPECT_NEAR(tg.finish(p, 0.5), 0.5 * mask.sum().item<double>(), 1e-12);
  EXPECT_TRUE(torch::equal(p.grad(), mask));
}

TEST(TableGradient, TheBufferHandedOutIsReusedOnlyWhenNobodyHoldsIt) {
  const HashGridShape s = small_shape();
  TableGradient tg(s);
  auto p = torch::ones({s.levels, s.table_size, s.features}).set_requires_grad(true);
  tg.finish(p, 1.0);
  const auto held = p.grad();  // someone keeps last step's gradient
  p.mutable_grad() = torch::Tensor();
  const auto one = some_lookup(s, 30, 4, false);
  tg.defer(0, one);
  tg.finish(p, 1.0);
  EXPECT_EQ(held[0][0][0].item<float>(), 2.f) << "a held gradient was written through";
  EXPECT_LT(test::max_abs(p.grad() - table_gradient_reference({}, {one}, p.detach(), s, 1.0)), 2e-5);
}

TEST(TableGradient, DiscardDropsTheLookups) {
  const HashGridShape s = small_shape();
  TableGradient tg(s);
  tg.defer(1, some_lookup(s, 10, 1, false));
  EXPECT_TRUE(tg.pending());
  tg.discard();
  EXPECT_FALSE(tg.pending());
  auto p = torch::ones({s.levels, s.table_size, s.features}).set_requires_grad(true);
  EXPECT_EQ(tg.finish(p, 0.0), 0.0);
  EXPECT_FALSE(p.grad().defined());
}

TEST(TableGradient, ScopesNestAndRestore) {
  EXPECT_EQ(TableGradient::current_key(), -1);
  {
    const TableGradientScope a(2);
    EXPECT_EQ(TableGradient::current_key(), 2);
    {
      const TableGradientScope b(0);
      EXPECT_EQ(TableGradient::current_key(), 0);
    }
    EXPECT_EQ(TableGradient::current_key(), 2);
  }
  EXPECT_EQ(TableGradient::current_key(), -1);
}

TEST(TableGradient, RejectsWhatItCannotHold) {
  const HashGridShape s = small_shape();
  TableGradient tg(s);
  const auto good = some_lookup(s, 8, 1, true);
  test::expect_error_naming([&] { tg.defer(-1, good); }, "key");
  test::expect_error_naming([&] { tg.defer(0, {good.positions.to(torch::kDouble), good.grad_out, {}}); }, "positions");
  test::expect_error_naming([&] { tg.defer(0, {good.positions, good.grad_out.slice(1, 0, 2), {}}); }, "grad_out");
  test::expect_error_naming([&] { tg.defer(0, {good.positions, good.grad_out, good.scales.t()}); }, "scales");
  EXPECT_FALSE(tg.pending());
  tg.defer(0, good);
  auto wrong = torch::zeros({s.levels, s.table_size + 1, s.features}).set_requires_grad(true);
  test::expect_error_naming([&] { tg.finish(wrong, 0.0); }, "parameter");
}

// Points of the unit cube and a loss weight per output (so that every level and feature counts differently).
struct Lookup {
  HashGridShape shape = small_shape();
  torch::Tensor table = table_of(shape, 3);
  torch::Tensor positions = torch::rand({300, 3}, at::detail::createCPUGenerator(5));
  torch::Tensor weights = test::seeded_randn({300, 4, 2}, 6).to(torch::kFloat);
};

TEST(TableGradient, HashGridLookupsDeferAutogradsGradient) {
  const Lookup l;
  // The reference: the plain LibTorch lookup, differentiated by autograd.
  auto ref_table = l.table.clone().set_requires_grad(true);
  auto ref_pos = l.positions.clone().set_requires_grad(true);
  (hash_grid_encode_reference(ref_pos, ref_table, l.shape) * l.weights).sum().backward();

  TableGradient tg(l.shape);
  auto table = l.table.clone().set_requires_grad(true);
  auto pos = l.positions.clone().set_requires_grad(true);
  {
    const TableGradientScope key(1);
    // Two uses of the table in one graph, as the coarse and the fine pass make.
    const auto half = l.weights * 0.5;
    const auto a = (hash_grid_encode(pos, table, l.shape, &tg) * half).sum();
    const auto b = (hash_grid_encode(pos, table, l.shape, &tg) * half).sum();
    (a + b).backward();
  }
  EXPECT_FALSE(table.grad().defined()) << "autograd got the table's gradient as well";
  ASSERT_TRUE(pos.grad().defined());
  EXPECT_TRUE(torch::allclose(pos.grad(), ref_pos.grad(), 1e-4, 1e-4));
  EXPECT_TRUE(tg.pending());
  EXPECT_GT(ref_table.grad().abs().sum().item<double>(), 1.0);
  tg.finish(table, 0.0);
  EXPECT_TRUE(torch::allclose(table.grad(), ref_table.grad(), 1e-5, 1e-5));
}

TEST(TableGradient, TwoThreadsDeferHalvesThatAddUpToTheWholeGradient) {
  const Lookup l;
  auto ref_table = l.table.clone().set_requires_grad(true);
  (hash_grid_encode_reference(l.positions, ref_table, l.shape) * l.weights).sum().backward();

  TableGradient tg(l.shape);
  auto table = l.table.clone().set_requires_grad(true);
  const auto half = [&](int k) {
    const TableGradientScope key(k);
    const auto rows = torch::indexing::Slice(k * 150, (k + 1) * 150);
    (hash_grid_encode(l.positions.index({rows}).contiguous(), table, l.shape, &tg) * l.weights.index({rows}))
        .sum()
        .backward();
  };
  std::thread other(half, 1);
  half(0);
  other.join();
  EXPECT_FALSE(table.grad().defined());
  tg.finish(table, 0.0);
  EXPECT_TRUE(torch::allclose(table.grad(), ref_table.grad(), 1e-5, 1e-5));
}

TEST(TableGradient, WithoutAKeyOrGradientModeAutogradKeepsTheTable) {
  const Lookup l;
  TableGradient tg(l.shape);
  auto table = l.table.clone().set_requires_grad(true);
  (hash_grid_encode(l.positions, table, l.shape, &tg) * l.weights).sum().backward();
  EXPECT_TRUE(table.grad().defined());
  EXPECT_FALSE(tg.pending());
  {
    const TableGradientScope key(0);
    const torch::NoGradGuard no_grad;
    const auto out = hash_grid_encode(l.positions, table, l.shape, &tg);
    EXPECT_FALSE(out.requires_grad());
  }
  EXPECT_FALSE(tg.pending());
}

}  // namespace
}  // namespace ablenerf
