// Scratch driver behind the training profile of docs/BENCHMARKS.md (LibTorch legacy profiler, two
// accumulate_gradients steps of 64 rays after one warm-up). Build as ab_compute.cpp; run: /tmp/prof2 trace.json
#include <torch/torch.h>
#include <torch/csrc/autograd/profiler_legacy.h>
#include "model/able_nerf.h"
#include "train/grad_accumulation.h"
#include "util/config.h"
using namespace ablenerf;
int main(int argc, char** argv) {
  Config c = Config::load("configs/blender.toml");
  torch::manual_seed(0);
  AbleNerf m(c.model);
  int64_t n = 64;
  auto o = torch::nn::functional::normalize(torch::randn({n, 3})) * 4.0;
  auto d = -o / 4.0 + 0.1 * torch::randn({n, 3});
  Rays r{o, d, torch::full({n, 1}, 5.196e-4f)};
  RayBatch batch{r, torch::full({n, 3}, 0.5f)};
  m->train();
  for (int i = 0; i < 1; ++i) accumulate_gradients(m, batch, n, c.train, n, 2, 6);
  torch::autograd::profiler::RecordProfile p(argv[1]);
  for (int i = 0; i < 2; ++i) accumulate_gradients(m, batch, n, c.train, n, 2, 6);
}
