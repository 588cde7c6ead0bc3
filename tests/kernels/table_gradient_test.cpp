// A table's gradient gathered in slots (kernels/table_gradient.h): finish() against its LibTorch
// reference and the decay's closed form, the slots zeroed after it and after discard(); hash-grid
// lookups with a slot open write exactly the gradient autograd gives the plain reference lookup,
// from two threads into two slots at once, while autograd gets none for the table and still gives
// the positions theirs; without a slot (or without gradient mode) nothing goes to the slots.
#include <gtest/gtest.h>

#include <limits>
#include <thread>

#include "kernels/hash_grid.h"
#include "kernels/kernel_test_util.h"
#include "kernels/table_gradient.h"

namespace ablenerf {
namespace {

torch::Tensor slot_tensor(TableGradient& tg, const torch::Tensor& table, int k) {
  return torch::from_blob(tg.slot(table, k), table.sizes(), torch::kFloat).clone();
}

// Every instruction form this CPU runs (the scalar one always), on a table whose size leaves a
// partial vector and one whose size does not.
TEST(TableGradient, FinishAddsTheSlotsAndTheDecayInOnePass) {
  for (const int64_t rows : {int64_t(40), int64_t(41)}) {
    for (const CpuVectorForm form : {CpuVectorForm::Scalar, CpuVectorForm::Avx512}) {
      if (!cpu_vector_form_available(form)) continue;
      const auto param = test::seeded_randn({3, rows, 2}, 1).to(torch::kFloat);
      for (const bool with_grad : {false, true}) {
        for (const double decay : {0.0, 0.125}) {
          TableGradient tg;
          std::vector<torch::Tensor> slots;
          for (int k = 0; k < 3; ++k) {
            const auto v = test::seeded_randn({3, rows, 2}, 10 + k).to(torch::kFloat);
            torch::from_blob(tg.slot(param, k), param.sizes(), torch::kFloat).copy_(v);
            slots.push_back(v);
          }
          auto p = param.clone().set_requires_grad(true);
          const auto before = test::seeded_randn({3, rows, 2}, 7).to(torch::kFloat);
          if (with_grad) p.mutable_grad() = before.clone();
          EXPECT_TRUE(tg.pending());
          const double value = tg.finish(p, decay, form);
          const auto want = table_gradient_reference(with_grad ? before : torch::Tensor(), slots, param, decay);
          EXPECT_TRUE(torch::allclose(p.grad(), want, 0, 0)) << with_grad << " " << decay << " " << rows;
          EXPECT_NEAR(value, decay * param.to(torch::kDouble).pow(2).sum().item<double>(), 1e-9);
          EXPECT_FALSE(tg.pending());
          for (int k = 0; k < 3; ++k) EXPECT_EQ(slot_tensor(tg, param, k).abs().max().item<float>(), 0.f) << k;
        }
      }
    }
  }
}

// With the entries lookups reach set (set_entries), finish() writes the reference's gradient there
// and 0 elsewhere, sums the squares of those entries only, and zeroes the slots; a gradient already
// on the parameter makes it write every entry again.
TEST(TableGradient, FinishWithEntriesWritesOnlyThoseAndZeroElsewhere) {
  const IndexRanges entries{{0, 10}, {30, 47}, {60, 240}};
  const auto inside = torch::zeros({240}, torch::kBool);
  for (const auto& r : entries) inside.slice(0, r.first, r.second).fill_(true);
  const auto mask = inside.view({3, 40, 2});
  for (const CpuVectorForm form : {CpuVectorForm::Scalar, CpuVectorForm::Avx512}) {
    if (!cpu_vector_form_available(form)) continue;
    const auto param = test::seeded_randn({3, 40, 2}, 3).to(torch::kFloat);
    TableGradient tg;
    tg.set_entries(entries);
    for (int step = 0; step < 2; ++step) {  // the second reuses the buffer
      std::vector<torch::Tensor> slots;
      for (int k = 0; k < 2; ++k) {
        // Lookups write only where they can reach.
        const auto v = test::seeded_randn({3, 40, 2}, 20 + k + step).to(torch::kFloat) * mask;
        torch::from_blob(tg.slot(param, k), param.sizes(), torch::kFloat).copy_(v);
        slots.push_back(v);
      }
      auto p = param.clone().set_requires_grad(true);
      const double value = tg.finish(p, 0.125, form);
      const auto want = table_gradient_reference(torch::Tensor(), slots, param, 0.125) * mask;
      EXPECT_TRUE(torch::allclose(p.grad(), want, 0, 0)) << "step " << step;
      EXPECT_NEAR(value, 0.125 * (param.to(torch::kDouble) * mask).pow(2).sum().item<double>(), 1e-9);
      EXPECT_TRUE(tg.wrote_finite_gradient());
      for (int k = 0; k < 2; ++k) EXPECT_EQ(slot_tensor(tg, param, k).abs().max().item<float>(), 0.f);
    }
    // A gradient before: every entry, as without entries.
    const auto v = test::seeded_randn({3, 40, 2}, 30).to(torch::kFloat) * mask;
    torch::from_blob(tg.slot(param, 0), param.sizes(), torch::kFloat).copy_(v);
    auto p = param.clone().set_requires_grad(true);
    const auto before = test::seeded_randn({3, 40, 2}, 31).to(torch::kFloat);
    p.mutable_grad() = before.clone();
    tg.finish(p, 0.125, form);
    EXPECT_TRUE(torch::allclose(p.grad(), table_gradient_reference(before, {v}, param, 0.125), 0, 0));
    // And back to the entries: 0 outside them again.
    torch::from_blob(tg.slot(param, 0), param.sizes(), torch::kFloat).copy_(v);
    auto q = param.clone().set_requires_grad(true);
    tg.finish(q, 0.125, form);
    EXPECT_TRUE(torch::allclose(q.grad(), table_gradient_reference(torch::Tensor(), {v}, param, 0.125) * mask, 0, 0));
  }
  TableGradient bad;
  EXPECT_THROW(bad.set_entries({{10, 20}, {15, 30}}), c10::Error);
}

// finish() says whether the gradient it wrote is finite: an infinity or NaN in any slot, at the
// first entry, inside the 16-wide vectors and in their tail, is found by every form; a pass that
// wrote nothing vouches for nothing.
TEST(TableGradient, FinishFindsAnInfiniteOrNaNEntry) {
  const int64_t rows = 41;  // 3 x 41 x 2 = 246 entries: 15 vectors and a tail of 6
  for (const CpuVectorForm form : {CpuVectorForm::Scalar, CpuVectorForm::Avx512}) {
    if (!cpu_vector_form_available(form)) continue;
    const auto param = test::seeded_randn({3, rows, 2}, 1).to(torch::kFloat);
    for (const float bad : {std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity(),
                            -std::numeric_limits<float>::infinity(), 0.0f}) {
      for (const int64_t at : {int64_t(0), int64_t(100), int64_t(245)}) {
        for (const int k : {0, 1}) {
          TableGradient tg;
          for (int j = 0; j < 2; ++j)
            torch::from_blob(tg.slot(param, j), param.sizes(), torch::kFloat)
                .copy_(test::seeded_randn({3, rows, 2}, 10 + j).to(torch::kFloat));
          tg.slot(param, k)[at] = bad;
          auto p = param.clone().set_requires_grad(true);
          tg.finish(p, 0.125, form);
          EXPECT_EQ(tg.wrote_finite_gradient(), bad == 0.0f) << bad << " at " << at << " in slot " << k;
          EXPECT_EQ(p.grad().isfinite().all().item<bool>(), bad == 0.0f);
        }
      }
    }
  }
  TableGradient tg;
  auto p = torch::ones({2, 8, 2}).set_requires_grad(true);
  tg.finish(p, 0.0);
  EXPECT_FALSE(tg.wrote_finite_gradient());
}

TEST(TableGradient, NothingWrittenAndNoDecayLeavesTheGradientAlone) {
  TableGradient tg;
  auto p = torch::ones({2, 8, 2}).set_requires_grad(true);
  EXPECT_EQ(tg.finish(p, 0.0), 0.0);
  EXPECT_FALSE(p.grad().defined());
  // The decay alone still makes a gradient.
  EXPECT_NEAR(tg.finish(p, 0.5), 0.5 * 32, 1e-12);
  EXPECT_TRUE(torch::allclose(p.grad(), torch::ones({2, 8, 2})));
}

TEST(TableGradient, TheBufferHandedOutIsReusedOnlyWhenNobodyHoldsIt) {
  TableGradient tg;
  auto p = torch::ones({1, 4, 2}).set_requires_grad(true);
  tg.finish(p, 1.0);
  const auto held = p.grad();  // someone keeps last step's gradient
  p.mutable_grad() = torch::Tensor();
  tg.slot(p, 0)[0] = 5.f;
  tg.finish(p, 1.0);
  EXPECT_EQ(held[0][0][0].item<float>(), 2.f) << "a held gradient was written through";
  EXPECT_EQ(p.grad()[0][0][0].item<float>(), 7.f);
}

TEST(TableGradient, DiscardZeroesTheSlots) {
  TableGradient tg;
  const auto table = torch::zeros({2, 16, 2});
  tg.slot(table, 1)[5] = 3.f;
  EXPECT_TRUE(tg.pending());
  tg.discard();
  EXPECT_FALSE(tg.pending());
  EXPECT_EQ(slot_tensor(tg, table, 1).abs().max().item<float>(), 0.f);
}

TEST(TableGradient, ScopesNestAndRestore) {
  EXPECT_EQ(TableGradient::current_slot(), -1);
  {
    const TableGradientScope a(2);
    EXPECT_EQ(TableGradient::current_slot(), 2);
    {
      const TableGradientScope b(0);
      EXPECT_EQ(TableGradient::current_slot(), 0);
    }
    EXPECT_EQ(TableGradient::current_slot(), 2);
  }
  EXPECT_EQ(TableGradient::current_slot(), -1);
}

TEST(TableGradient, RejectsWhatItCannotHold) {
  TableGradient tg;
  EXPECT_THROW(tg.slot(torch::zeros({2, 4, 2}, torch::kDouble), 0), c10::Error);
  EXPECT_THROW(tg.slot(torch::zeros({2, 4, 2}), -1), c10::Error);
}

// Points of the unit cube and a loss weight per output (so that every level and feature counts differently).
struct Lookup {
  HashGridShape shape = hash_grid_shape(4, 2, 7, 4, 32);  // a dense level and hashed ones
  torch::Tensor table = test::seeded_randn({4, 128, 2}, 3).to(torch::kFloat);
  torch::Tensor positions = torch::rand({300, 3}, at::detail::createCPUGenerator(5));
  torch::Tensor weights = test::seeded_randn({300, 4, 2}, 6).to(torch::kFloat);
};

TEST(TableGradient, HashGridLookupsWriteAutogradsGradientToTheirSlot) {
  const Lookup l;
  // The reference: the plain LibTorch lookup, differentiated by autograd.
  auto ref_table = l.table.clone().set_requires_grad(true);
  auto ref_pos = l.positions.clone().set_requires_grad(true);
  (hash_grid_encode_reference(ref_pos, ref_table, l.shape) * l.weights).sum().backward();

  TableGradient tg;
  auto table = l.table.clone().set_requires_grad(true);
  auto pos = l.positions.clone().set_requires_grad(true);
  {
    const TableGradientScope slot(1);
    // Two uses of the table in one graph, as the coarse and the fine pass make.
    const auto half = l.weights * 0.5;
    const auto a = (hash_grid_encode(pos, table, l.shape, &tg) * half).sum();
    const auto b = (hash_grid_encode(pos, table, l.shape, &tg) * half).sum();
    (a + b).backward();
  }
  EXPECT_FALSE(table.grad().defined()) << "autograd got the table's gradient as well";
  ASSERT_TRUE(pos.grad().defined());
  EXPECT_TRUE(torch::allclose(pos.grad(), ref_pos.grad(), 1e-4, 1e-4));
  EXPECT_TRUE(torch::allclose(slot_tensor(tg, table, 1), ref_table.grad(), 1e-5, 1e-5));
  EXPECT_GT(ref_table.grad().abs().sum().item<double>(), 1.0);
  tg.finish(table, 0.0);
  EXPECT_TRUE(torch::allclose(table.grad(), ref_table.grad(), 1e-5, 1e-5));
}

TEST(TableGradient, TwoThreadsWriteTwoSlotsThatAddUpToTheWholeGradient) {
  const Lookup l;
  auto ref_table = l.table.clone().set_requires_grad(true);
  (hash_grid_encode_reference(l.positions, ref_table, l.shape) * l.weights).sum().backward();

  TableGradient tg;
  auto table = l.table.clone().set_requires_grad(true);
  const auto half = [&](int k) {
    const TableGradientScope slot(k);
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

TEST(TableGradient, WithoutASlotOrGradientModeAutogradKeepsTheTable) {
  const Lookup l;
  TableGradient tg;
  auto table = l.table.clone().set_requires_grad(true);
  (hash_grid_encode(l.positions, table, l.shape, &tg) * l.weights).sum().backward();
  EXPECT_TRUE(table.grad().defined());
  EXPECT_FALSE(tg.pending());
  {
    const TableGradientScope slot(0);
    const torch::NoGradGuard no_grad;
    const auto out = hash_grid_encode(l.positions, table, l.shape, &tg);
    EXPECT_FALSE(out.requires_grad());
  }
  EXPECT_FALSE(tg.pending());
}

}  // namespace
}  // namespace ablenerf
