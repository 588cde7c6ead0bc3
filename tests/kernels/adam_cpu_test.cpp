// Adam's element-wise update on the CPU (kernels/adam_cpu.h): every form this CPU runs (the scalar
// one always, the fallback of a CPU without AVX-512) against a plain LibTorch reference written from
// the formulas, in float64, and against each other to the bit; lengths that leave a partial vector
// and slices that start off a vector boundary.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <stdexcept>

#include "kernels/adam_cpu.h"

namespace ablenerf {
namespace {

struct State {
  torch::Tensor g, m, v, w;
};

State random_state(int64_t n, uint64_t seed) {
  torch::manual_seed(seed);
  // Gradients over several orders of magnitude, zeros among them (an untouched table row).
  auto g = torch::randn({n}) * torch::pow(10.0, torch::randint(-6, 2, {n}).to(torch::kFloat));
  g.masked_fill_(torch::rand({n}) < 0.2, 0.0);
  return {g, torch::randn({n}) * 1e-3, torch::rand({n}) * 1e-4, torch::randn({n}) * 1e-2};
}

TEST(AdamCpu, EveryFormFollowsTheFormulasAndTheFormsAgreeToTheBit) {
  const double beta1 = 0.9, beta2 = 0.999, eps = 1e-8, lr = 2e-3;
  const int step = 7;
  const double bias1 = 1 - std::pow(beta1, step), bias2 = 1 - std::pow(beta2, step);
  const AdamScalars s{float(beta1), float(1 - beta1),        float(beta2),      float(1 - beta2),
                      float(eps),   float(std::sqrt(bias2)), float(-lr / bias1)};
  int ran = 0;
  for (const int64_t n : {int64_t(1), int64_t(15), int64_t(16), int64_t(17), int64_t(1003)}) {
    const State start = random_state(n, uint64_t(n));
    // The reference: the formulas in float64 on the same inputs.
    const auto g = start.g.to(torch::kDouble), m0 = start.m.to(torch::kDouble), v0 = start.v.to(torch::kDouble);
    const auto m_ref = m0 * beta1 + (1 - beta1) * g;
    const auto v_ref = v0 * beta2 + (1 - beta2) * g * g;
    const auto w_ref = start.w.to(torch::kDouble) - (lr / bias1) * m_ref / (v_ref.sqrt() / std::sqrt(bias2) + eps);
    torch::Tensor first_w, first_m, first_v;
    for (const CpuVectorForm form : {CpuVectorForm::Scalar, CpuVectorForm::Avx512}) {
      if (!cpu_vector_form_available(form)) continue;
      ++ran;
      // Two slices, the second starting at an odd offset, as the threads of the update split it.
      State st{start.g, start.m.clone(), start.v.clone(), start.w.clone()};
      const int64_t cut = n / 3;
      for (const auto& [lo, hi] : {std::pair<int64_t, int64_t>{0, cut}, {cut, n}})
        adam_update_cpu_in(form, hi - lo, st.g.data_ptr<float>() + lo, st.m.data_ptr<float>() + lo,
                           st.v.data_ptr<float>() + lo, st.w.data_ptr<float>() + lo, s);
      // Absolute slack for m: where b1 m and (1 - b1) g cancel, float32 keeps about one ulp of the
      // inputs (m ~ 1e-3, ulp ~ 1e-10).
      EXPECT_TRUE(torch::allclose(st.m.to(torch::kDouble), m_ref, 1e-6, 3e-10)) << "n " << n;
      EXPECT_TRUE(torch::allclose(st.v.to(torch::kDouble), v_ref, 1e-6, 1e-18)) << "n " << n;
      EXPECT_TRUE(torch::allclose(st.w.to(torch::kDouble), w_ref, 1e-6, 1e-9)) << "n " << n;
      // The step moved the parameters (a wrong sign or scale would fail above; this guards a no-op).
      EXPECT_GT((st.w - start.w).abs().max().item<double>(), 1e-4) << "n " << n;
      if (!first_w.defined()) {
        first_w = st.w, first_m = st.m, first_v = st.v;
        continue;
      }
      EXPECT_TRUE(torch::equal(st.w, first_w)) << "n " << n;
      EXPECT_TRUE(torch::equal(st.m, first_m)) << "n " << n;
      EXPECT_TRUE(torch::equal(st.v, first_v)) << "n " << n;
    }
  }
  EXPECT_GE(ran, 5);  // the scalar form ran at every length
}

AdamScalars some_scalars() {
  const double beta1 = 0.9, beta2 = 0.999, eps = 1e-8, lr = 2e-3;
  const int step = 7;
  const double bias1 = 1 - std::pow(beta1, step), bias2 = 1 - std::pow(beta2, step);
  return {float(beta1), float(1 - beta1),        float(beta2),      float(1 - beta2),
          float(eps),   float(std::sqrt(bias2)), float(-lr / bias1)};
}

// The update with the gradient formed on the way (a grid table's): g = sum + two_decay x w in
// float32, then adam_update_cpu's update, to the bit, in every form; the squares of w before the
// update; entries whose g is not finite (a NaN or infinite sum, an infinite w) keep their values
// and clear `finite`, the others update as without them.
TEST(AdamCpu, TheDecayedUpdateIsTheSumThenTheUpdate) {
  const AdamScalars s = some_scalars();
  const float two_decay = 0.25f;
  for (const int64_t n : {int64_t(1), int64_t(17), int64_t(1003)}) {
    const State start = random_state(n, uint64_t(n) + 100);
    const auto sum = start.g;
    // The plain sequence: the gradient as float32 tensor ops (one rounding each), then the update.
    const auto g = sum + (start.w * two_decay);
    State want{g, start.m.clone(), start.v.clone(), start.w.clone()};
    adam_update_cpu_in(CpuVectorForm::Scalar, n, want.g.data_ptr<float>(), want.m.data_ptr<float>(),
                       want.v.data_ptr<float>(), want.w.data_ptr<float>(), s);
    const double squares = start.w.to(torch::kDouble).pow(2).sum().item<double>();
    for (const CpuVectorForm form : {CpuVectorForm::Scalar, CpuVectorForm::Avx512}) {
      if (!cpu_vector_form_available(form)) continue;
      State st{sum, start.m.clone(), start.v.clone(), start.w.clone()};
      bool finite = true;
      const double got = adam_update_decayed_cpu_in(form, n, st.g.data_ptr<float>(), two_decay, st.m.data_ptr<float>(),
                                                    st.v.data_ptr<float>(), st.w.data_ptr<float>(), s, finite);
      EXPECT_TRUE(finite);
      EXPECT_NEAR(got, squares, 1e-12 * squares) << "n " << n;
      EXPECT_TRUE(torch::equal(st.w, want.w)) << "n " << n;
      EXPECT_TRUE(torch::equal(st.m, want.m)) << "n " << n;
      EXPECT_TRUE(torch::equal(st.v, want.v)) << "n " << n;
    }
  }
  // Not finite: a NaN and an infinite sum, an infinite w, at the first entry, inside the vectors
  // and in the tail.
  const int64_t n = 37;
  for (const int64_t at : {int64_t(0), int64_t(20), int64_t(36)}) {
    for (int kind = 0; kind < 3; ++kind) {
      for (const CpuVectorForm form : {CpuVectorForm::Scalar, CpuVectorForm::Avx512}) {
        if (!cpu_vector_form_available(form)) continue;
        const State start = random_state(n, 5);
        State st{start.g.clone(), start.m.clone(), start.v.clone(), start.w.clone()};
        if (kind == 0) st.g[at] = std::nanf("");
        if (kind == 1) st.g[at] = INFINITY;
        if (kind == 2) st.w[at] = -INFINITY;
        const auto w_before = st.w.clone();
        State clean{start.g.clone(), start.m.clone(), start.v.clone(), start.w.clone()};
        bool finite = true, clean_finite = true;
        adam_update_decayed_cpu_in(form, n, st.g.data_ptr<float>(), two_decay, st.m.data_ptr<float>(),
                                   st.v.data_ptr<float>(), st.w.data_ptr<float>(), s, finite);
        adam_update_decayed_cpu_in(form, n, clean.g.data_ptr<float>(), two_decay, clean.m.data_ptr<float>(),
                                   clean.v.data_ptr<float>(), clean.w.data_ptr<float>(), s, clean_finite);
        EXPECT_FALSE(finite) << "kind " << kind << " at " << at;
        EXPECT_TRUE(clean_finite);
        EXPECT_EQ(st.m[at].item<float>(), start.m[at].item<float>()) << "kind " << kind << " at " << at;
        EXPECT_EQ(st.v[at].item<float>(), start.v[at].item<float>());
        EXPECT_TRUE(torch::equal(st.w[at], w_before[at]));
        const auto others = torch::arange(n) != at;
        EXPECT_TRUE(torch::equal(st.w.index({others}), clean.w.index({others}))) << "kind " << kind << " at " << at;
        EXPECT_TRUE(torch::equal(st.m.index({others}), clean.m.index({others})));
      }
    }
  }
}

TEST(AdamCpu, AFormThisCpuLacksIsRefused) {
  if (cpu_vector_form_available(CpuVectorForm::Avx512)) GTEST_SKIP() << "this CPU runs every form";
  float x = 0;
  EXPECT_THROW(adam_update_cpu_in(CpuVectorForm::Avx512, 1, &x, &x, &x, &x, AdamScalars{}), std::invalid_argument);
  bool finite = true;
  EXPECT_THROW(adam_update_decayed_cpu_in(CpuVectorForm::Avx512, 1, &x, 0.f, &x, &x, &x, AdamScalars{}, finite),
               std::invalid_argument);
}

}  // namespace
}  // namespace ablenerf
