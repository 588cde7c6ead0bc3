#pragma once
// Stage 6a (docs/MODEL.md, section 6): the Fourier code e_d of the ray's unnormalised direction d that feeds
// the view token and, again, the LE colour head.
#include <torch/torch.h>

#include "model/model_config.h"

namespace ablenerf {

// Width of e_d for a model.view_encoding value: "release" -> 27, "paper" -> 99.
int64_t view_encoding_width(ViewEncoding kind);

// d: (B,3) -> (B, width). Layout [d, sin(f1 d), cos(f1 d), sin(f2 d), cos(f2 d), ...] (per
// frequency: sin of xyz, then cos of xyz).
//  * "release": f = linspace(1, 8, 4) (4 linear bands, no pi factor) as the authors' code.
//  * "paper": the paper's "16 bands" read as octaves f = 2^0 .. 2^15 (the NeRF positional-
//    encoding convention; the paper gives no spacing). No pi factor, like the release.
torch::Tensor encode_view(const torch::Tensor& directions, ViewEncoding kind);

}  // namespace ablenerf
