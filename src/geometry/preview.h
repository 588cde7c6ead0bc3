#pragma once
// A picture of exported geometry with the cameras that saw it (`export --preview`, the run's
// report): an orthographic view of the points from above the scene (the scene frame's +z is up,
// data/scene_frame.h), each point one pixel in its rendered colour, the nearest in front, and each
// camera as a small pyramid of lines from its centre to its image's four corners. The geometry and
// the cameras come from one frame, so a mesh that lies where the photos put it shows the pyramids
// pointing at it.
#include <torch/torch.h>

#include "data/camera.h"

namespace ablenerf {

struct PreviewOptions {
  int width = 960, height = 720;
  double azimuth_deg = 45;    // about +z, from +x towards +y
  double elevation_deg = 35;  // above the xy plane
  double frustum = 0.06;      // a pyramid's depth, as a share of the picture's extent
};

// The view's orthonormal axes (3,3) float64, rows: right, up (on the screen) and towards the viewer.
torch::Tensor preview_axes(double azimuth_deg, double elevation_deg);

// xyz (N,3) and rgb (N,3) in [0,1] of the points, c2w (M,3,4) of the cameras (OpenGL axes, as
// data/rays.h) with their intrinsics `k`, all in one frame; returns a float (H,W,3) image in [0,1].
// The picture holds the central 98% of the points on each axis and every camera centre, with a
// 5% margin.
torch::Tensor draw_preview(const torch::Tensor& xyz, const torch::Tensor& rgb, const torch::Tensor& c2w,
                           const Intrinsics& k, const PreviewOptions& opts = {});

}  // namespace ablenerf
