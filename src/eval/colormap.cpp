#include "eval/colormap.h"

#include <array>

namespace ablenerf {
namespace {
// viridis sampled at 0, 0.25, 0.5, 0.75, 1 (published matplotlib values, rounded to 3 digits).
constexpr int kStops = 5;
constexpr std::array<std::array<float, 3>, kStops> kViridis{{
    {0.267f, 0.005f, 0.329f},
    {0.229f, 0.322f, 0.546f},
    {0.128f, 0.567f, 0.551f},
    {0.369f, 0.789f, 0.383f},
    {0.993f, 0.906f, 0.144f},
}};
}  // namespace

torch::Tensor colormap(const torch::Tensor& values, double lo, double hi) {
  TORCH_CHECK(values.dim() == 2, "colormap: expected an (H,W) tensor, got ", values.sizes());
  TORCH_CHECK(hi > lo, "colormap: empty range [", lo, ", ", hi, "]");
  auto v = values.detach().to(torch::kCPU, torch::kFloat);
  auto x = torch::nan_to_num((v - lo) / (hi - lo), 0.0).clamp(0.0, 1.0) * (kStops - 1);
  auto left = x.floor().clamp(0, kStops - 2).to(torch::kLong);  // segment index
  auto frac = (x - left.to(torch::kFloat)).unsqueeze(-1);       // position inside the segment
  auto table = torch::empty({kStops, 3}, torch::kFloat);
  for (int i = 0; i < kStops; ++i)
    for (int c = 0; c < 3; ++c) table[i][c] = kViridis[static_cast<size_t>(i)][static_cast<size_t>(c)];
  auto a = table.index({left}), b = table.index({left + 1});
  return a + (b - a) * frac;
}

}  // namespace ablenerf
