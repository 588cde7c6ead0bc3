// Model throughput: forward (inference, no grad) and forward+backward (training step without
// the optimiser) in rays/s (items_per_second) at batch 64, for the paper and demo presets.
#include <benchmark/benchmark.h>
#include <torch/torch.h>

#include <string>

#include "model/able_nerf.h"

namespace {

constexpr int64_t kBatch = 64;
constexpr double kNear = 2.0, kFar = 6.0;

ablenerf::Rays bench_rays() {
  // Blender-like rays: cameras on a radius-4 shell looking roughly at the origin.
  const auto o = torch::nn::functional::normalize(torch::randn({kBatch, 3})) * 4.0;
  const auto d = -o / 4.0 + 0.1 * torch::randn({kBatch, 3});
  return {o, d, torch::full({kBatch, 1}, 5.196e-4f)};
}

void BM_Model(benchmark::State& state, const std::string& preset, bool backward) {
  const auto cfg = ablenerf::Config::load(std::string(ABLENERF_SOURCE_DIR) + "/configs/" + preset + ".toml");
  torch::manual_seed(4);
  ablenerf::AbleNerf model(cfg.model);
  const auto rays = bench_rays();
  const auto target = torch::full({kBatch, 3}, 0.5f);
  if (backward) model->train();
  else model->eval();
  for (auto _ : state) {
    if (backward) {
      model->zero_grad();
      const auto out = model->forward(rays, kNear, kFar);
      const auto loss = torch::mse_loss(out.rgb_coarse, target) + torch::mse_loss(out.rgb_fine, target);
      loss.backward();
      benchmark::DoNotOptimize(loss.item<float>());
    } else {
      torch::NoGradGuard no_grad;
      const auto out = model->forward(rays, kNear, kFar);
      benchmark::DoNotOptimize(out.rgb_fine.sum().item<float>());
    }
  }
  state.SetItemsProcessed(state.iterations() * kBatch);
}

BENCHMARK_CAPTURE(BM_Model, blender_forward, std::string("blender"), false)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_Model, blender_train, std::string("blender"), true)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_Model, demo_forward, std::string("demo"), false)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_Model, demo_train, std::string("demo"), true)->Unit(benchmark::kMillisecond);

}  // namespace
