// Scratch driver behind the render profile of docs/BENCHMARKS.md (LibTorch legacy profiler, 3 forwards of
// 64 rays after 2 warm-ups; self time per op summed from the chrome trace). Build as ab_compute.cpp
// (only the model, data and util libraries are needed); run: /tmp/prof trace.json
#include <torch/torch.h>
#include <torch/csrc/autograd/profiler_legacy.h>
#include "model/able_nerf.h"
#include "util/config.h"
#include <iostream>
using namespace ablenerf;
int main(int argc, char** argv) {
  Config c = Config::load("configs/blender.toml");
  if (argc > 2) c.compute.cpu_split = argv[2];
  torch::manual_seed(0);
  AbleNerf m(c.model);
  m->eval();
  int64_t n = 64;
  auto o = torch::nn::functional::normalize(torch::randn({n, 3})) * 4.0;
  auto d = -o / 4.0 + 0.1 * torch::randn({n, 3});
  Rays r{o, d, torch::full({n, 1}, 5.196e-4f)};
  ForwardOptions fo; fo.coarse_colour = false;
  torch::InferenceMode g;
  for (int i = 0; i < 2; ++i) m->forward(r, 2, 6, fo);
  {
    torch::autograd::profiler::RecordProfile p(argv[1]);
    for (int i = 0; i < 3; ++i) m->forward(r, 2, 6, fo);
  }
}
