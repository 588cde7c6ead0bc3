#pragma once
// A capture frame's depth file as a depth map: synth's pickled tensors (depth_file_path) and the
// depth maps of NeRF's Blender scenes (nerf_synthetic: test/r_N_depth_0001.png beside r_N.png).
// The release never documented how the 8-bit values map to depth (its authors say the files were
// shipped by mistake). Fitted here by multi-view consistency, independent of any trained model: each
// pixel of one view, moved out along its ray by the candidate depth and projected into the
// neighbouring view, must land on that view's depth. Over lego's test views 0, 10, ..., 190 the
// best of {linear, sRGB-decoded} x {distance along the ray, camera-space z} is
//   distance along the pixel-centre ray = 8 (1 - v / 255),   v = 0: background,
// with a median disagreement of 0.017 between neighbouring views (half of one 8-bit step, 0.031);
// z-depth with the same constants disagrees by 0.038, constants 1% off by 0.020-0.170
// (docs/benchmarks/history.md, "Blender's depth maps"; the test that checks it on lego:
// tests/data/depth_file_test.cpp).
#include <torch/torch.h>

#include <string>

#include "data/capture.h"

namespace ablenerf {

// The distance a value of 255 would stand for: v = 0 is the background, v = 255 the camera.
constexpr double kBlenderDepthRange = 8.0;

// A decoded depth PNG (uint8 (H, W, C), the first channel used) as camera-space depth along -z,
// the convention of the model's depth and of synth's depth files (float (H, W), 0 on the
// background): the ray distance over the length of the pixel-centre direction (x, y, -1) of `k`
// (a pinhole camera of the map's size).
torch::Tensor blender_depth_to_z(const torch::Tensor& png, const Intrinsics& k);

// The frame's depth file (fr.depth, in fr.depth_format) at the file's own size: float (H, W)
// camera-space depth along -z in the capture's units, 0 where nothing was hit. InputError naming
// the file on a file that cannot be read.
torch::Tensor read_frame_depth(const CaptureFrame& fr);

}  // namespace ablenerf
