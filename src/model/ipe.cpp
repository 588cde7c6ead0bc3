#include "model/ipe.h"

#include <cmath>

namespace ablenerf {

torch::Tensor integrated_pos_enc(const torch::Tensor& mean, const torch::Tensor& cov, int64_t degrees) {
  // Powers of two are exact in float, so 2^l * mean matches the release bit for bit.
  const auto scales = torch::pow(2.0, torch::arange(degrees, mean.options()));  // (L)
  const auto y = (mean.unsqueeze(-2) * scales.unsqueeze(-1)).flatten(-2);       // (...,3L): 3l+c
  const auto v = (cov.unsqueeze(-2) * (scales * scales).unsqueeze(-1)).flatten(-2);
  // The release writes the cosine as sin(y + pi/2); one sin over both halves reproduces it.
  const auto angles = torch::cat({y, y + M_PI / 2.0}, -1);
  const auto attenuation = torch::exp(-0.5 * v);
  return torch::cat({attenuation, attenuation}, -1) * torch::sin(angles);
}

}  // namespace ablenerf
