#pragma once
// The loader's rays against the renderer's: for a synth capture loaded as a Dataset, the largest
// difference between the ray the loader casts through a pixel of a training view and the ray the
// renderer cast through it (moved into the scene frame), over the views and pixels given.
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <utility>
#include <vector>

#include "data/dataset.h"
#include "data/rays.h"
#include "synth/camera.h"

namespace ablenerf::synth_test {

struct RayMismatch {
  double direction = 0, origin = 0;
};

// cams[i] is view i's renderer camera (lens included); pixels are (column, row) pairs.
inline RayMismatch loader_ray_mismatch(const Dataset& ds, const std::vector<synth::Camera>& cams,
                                       const std::vector<std::pair<double, double>>& pixels) {
  const auto& R = ds.scene.rotation;
  const auto& train = ds.split("train");
  RayMismatch worst;
  for (int64_t i = 0; i < static_cast<int64_t>(cams.size()); ++i) {
    for (const auto& [col, row] : pixels) {
      const Rays r = rays_for_pixels(train.c2w[i].unsqueeze(0).to(torch::kFloat64),
                                     torch::tensor({col}, torch::kFloat64), torch::tensor({row}, torch::kFloat64),
                                     CameraTable::of({train.cameras[static_cast<size_t>(i)]}));
      const synth::Ray s = synth::camera_ray(cams[static_cast<size_t>(i)], col + 0.5, row + 0.5);
      // The renderer's ray in the scene frame: origin moved, direction rotated (both have camera z = -1).
      const auto o_s = ds.scene.point_to_scene({s.origin.x, s.origin.y, s.origin.z});
      const double d[3] = {s.dir.x, s.dir.y, s.dir.z};
      for (int k = 0; k < 3; ++k) {
        const double dk = R[static_cast<size_t>(3 * k)] * d[0] + R[static_cast<size_t>(3 * k + 1)] * d[1] +
                          R[static_cast<size_t>(3 * k + 2)] * d[2];
        worst.direction = std::max(worst.direction, std::abs(r.directions[0][k].item<double>() - dk));
        worst.origin = std::max(worst.origin, std::abs(r.origins[0][k].item<double>() - o_s[static_cast<size_t>(k)]));
      }
    }
  }
  return worst;
}

}  // namespace ablenerf::synth_test
