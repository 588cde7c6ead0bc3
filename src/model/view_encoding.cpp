#include "model/view_encoding.h"

#include <stdexcept>

namespace ablenerf {

namespace {
constexpr int64_t kReleaseBands = 4;
constexpr double kReleaseMaxFreq = 8.0;  // 2^3: linspace(2^0, 2^3, 4)
constexpr int64_t kPaperBands = 16;
constexpr int64_t kAxes = 3;

torch::Tensor frequencies(const std::string& kind, const torch::TensorOptions& o) {
  if (kind == "release") return torch::linspace(1.0, kReleaseMaxFreq, kReleaseBands, o);
  if (kind == "paper") return torch::pow(2.0, torch::arange(kPaperBands, o));
  throw std::invalid_argument("unknown view encoding '" + kind + "'");
}
}  // namespace

int64_t view_encoding_width(const std::string& kind) {
  const int64_t bands = kind == "paper" ? kPaperBands : kReleaseBands;
  if (kind != "paper" && kind != "release") throw std::invalid_argument("unknown view encoding '" + kind + "'");
  return kAxes + 2 * kAxes * bands;
}

torch::Tensor encode_view(const torch::Tensor& d, const std::string& kind) {
  const auto f = frequencies(kind, d.options());
  const auto x = d.unsqueeze(1) * f.view({-1, 1});  // (B,F,3)
  // (B,F,2,3) -> (B, F*6): per frequency sin xyz then cos xyz.
  const auto sc = torch::stack({torch::sin(x), torch::cos(x)}, 2).flatten(1);
  return torch::cat({d, sc}, 1);
}

}  // namespace ablenerf
