// Scratch driver behind the "Within-process A/B" table of docs/BENCHMARKS.md (2026-11-22).
// Build from the repository root after `cmake --build build`:
//   g++ -O2 -std=c++17 -Isrc -I/usr/include/torch/csrc/api/include docs/results/cpu/drivers/ab_compute.cpp -o /tmp/ab \
//     build/libablenerf_train.a build/libablenerf_eval.a build/libablenerf_model.a build/libablenerf_data.a \
//     build/libablenerf_synth.a build/libablenerf_util.a /usr/lib/x86_64-linux-gnu/libtorch.so.1.13.0 \
//     /usr/lib/x86_64-linux-gnu/libtorch_cpu.so.1.13.0 /usr/lib/x86_64-linux-gnu/libc10.so -lpng -lpthread
// Run: /tmp/ab configs/blender.toml 5 0   (render, 5 rounds)   /tmp/ab configs/blender.toml 4 1   (train)
#include <torch/torch.h>
#include "model/able_nerf.h"
#include "model/compute.h"
#include "train/grad_accumulation.h"
#include "util/config.h"
#include <chrono>
#include <iostream>
#include <algorithm>
using namespace ablenerf;
double now() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }
int main(int argc, char** argv) {
  Config c = Config::load(argc > 1 ? argv[1] : "configs/blender.toml");
  int rounds = argc > 2 ? atoi(argv[2]) : 5;
  bool train = argc > 3 ? atoi(argv[3]) : 0;
  int64_t n = argc > 4 ? atoi(argv[4]) : 64;
  torch::manual_seed(0);
  AbleNerf m(c.model);
  auto o = torch::nn::functional::normalize(torch::randn({n, 3})) * 4.0;
  auto d = -o / 4.0 + 0.1 * torch::randn({n, 3});
  Rays r{o, d, torch::full({n, 1}, 5.196e-4f)};
  RayBatch batch{r, torch::full({n, 3}, 0.5f)};
  struct Cfg { AttentionKernel k; CpuSplit s; const char* name; };
  std::vector<Cfg> cfgs = {{AttentionKernel::Plain, CpuSplit::Ops, "plain+ops"}, {AttentionKernel::Fused, CpuSplit::Ops, "fused+ops"},
                           {AttentionKernel::Plain, CpuSplit::Rays, "plain+rays"}, {AttentionKernel::Fused, CpuSplit::Rays, "fused+rays"}};
  std::vector<std::vector<double>> t(cfgs.size());
  for (int rep = -1; rep < rounds; ++rep)
    for (size_t i = 0; i < cfgs.size(); ++i) {
      set_attention_kernel(cfgs[i].k); set_cpu_split(cfgs[i].s);
      double t0 = now();
      if (train) { m->train(); accumulate_gradients(m, batch, n, c.train, n, 2, 6); m->zero_grad(); }
      else { m->eval(); torch::InferenceMode g; ForwardOptions fo; fo.coarse_colour = false; m->forward(r, 2, 6, fo); }
      if (rep >= 0) t[i].push_back(now() - t0);
    }
  for (size_t i = 0; i < cfgs.size(); ++i) { auto v = t[i]; std::sort(v.begin(), v.end()); printf("%-12s median %.3f s  -> %.1f rays/s  (min %.3f max %.3f)\n", cfgs[i].name, v[v.size()/2], n / v[v.size()/2], v.front(), v.back()); }
}
