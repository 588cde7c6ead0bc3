#pragma once
// False-colour maps for scalar images (error and depth maps): a perceptually ordered
// dark-blue -> green -> yellow ramp (five anchor colours of matplotlib's viridis, linearly
// interpolated), so that larger values are always brighter.
#include <torch/torch.h>

namespace ablenerf {

// Maps a float (H,W) tensor through the ramp after normalising [lo, hi] -> [0, 1]
// (values outside are clamped; NaN maps to the low end). Returns float (H,W,3) in [0,1], on CPU.
torch::Tensor colormap(const torch::Tensor& values, double lo, double hi);

}  // namespace ablenerf
