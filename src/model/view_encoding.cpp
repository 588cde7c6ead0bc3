#include "model/view_encoding.h"
#include "model/model_config.h"

namespace ablenerf {

namespace {
constexpr int64_t kReleaseBands = 4;
constexpr double kReleaseMaxFreq = 8.0;  // 2^3: linspace(2^0, 2^3, 4)
constexpr int64_t kPaperBands = 16;
constexpr int64_t kAxes = 3;

torch::Tensor frequencies(ViewEncoding kind, const torch::TensorOptions& o) {
  if (kind == ViewEncoding::Paper) return torch::pow(2.0, torch::arange(kPaperBands, o));
  return torch::linspace(1.0, kReleaseMaxFreq, kReleaseBands, o);
}
}  // namespace

int64_t view_encoding_width(ViewEncoding kind) {
  const int64_t bands = kind == ViewEncoding::Paper ? kPaperBands : kReleaseBands;
  return kAxes + 2 * kAxes * bands;
}

torch::Tensor encode_view(const torch::Tensor& d, ViewEncoding kind) {
  const auto f = frequencies(kind, d.options());
  const auto x = d.unsqueeze(1) * f.view({-1, 1});  // (B,F,3)
  // (B,F,2,3) -> (B, F*6): per frequency sin xyz then cos xyz.
  const auto sc = torch::stack({torch::sin(x), torch::cos(x)}, 2).flatten(1);
  return torch::cat({d, sc}, 1);
}

}  // namespace ablenerf
