#pragma once
// Stage 2 (docs/MODEL.md, section 2): integrated positional encoding of Gaussians. For degree l and axis c,
// with y = 2^l mean_c and v = 4^l cov_c, the features are E[sin(y')] = exp(-v/2) sin(y) and
// E[cos(y')] = exp(-v/2) cos(y), at index 3l + c; all sines first, then all cosines.
#include <torch/torch.h>

namespace ablenerf {

// mean, cov: (...,3) -> (..., 6 * degrees). No raw xyz is appended (release behaviour).
torch::Tensor integrated_pos_enc(const torch::Tensor& mean, const torch::Tensor& cov, int64_t degrees);

// Output width for `degrees` frequencies.
inline int64_t ipe_width(int64_t degrees) { return 2 * 3 * degrees; }

}  // namespace ablenerf
