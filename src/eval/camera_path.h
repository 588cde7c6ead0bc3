#pragma once
// Camera paths for `ablenerf render`: an orbit (circle around the world z axis) or a spiral
// (the orbit with the elevation oscillating), every camera looking at the origin with +z up.
// Poses are camera-to-world (3,4) in the Blender/OpenGL convention (see data/rays.h): camera x
// right, y up, and the camera looks along its -z axis.
#include <torch/torch.h>

#include <string>

namespace ablenerf {

enum class PathKind { Orbit, Spiral };

// "orbit" / "spiral"; throws InputError(source, field, ...) otherwise.
PathKind parse_path_kind(const std::string& name, const std::string& source = "--path",
                         const std::string& field = "");

// Where the training cameras sit, seen from the origin.
struct CameraRig {
  double distance = 4.0;   // mean distance of the camera centres from the origin
  double elevation = 0.5;  // mean elevation angle above the xy plane, radians
};
// From (N,3,4) or (N,4,4) poses.
CameraRig camera_rig(const torch::Tensor& c2w);

// Largest |elevation| a path may reach: looking straight down the z axis makes "+z up" undefined.
constexpr double kMaxElevationRad = 1.4835298641951802;  // 85 degrees
// Half the peak-to-peak elevation swing of the spiral, radians (15 degrees).
constexpr double kSpiralAmplitudeRad = 0.2617993877991494;
// Full elevation oscillations of the spiral over one turn of azimuth.
constexpr int kSpiralCycles = 2;

// A camera at `eye` looking at `target` with the world `up` direction (float (3,4)).
// Throws std::invalid_argument when eye == target or the view direction is parallel to `up`.
torch::Tensor look_at(const torch::Tensor& eye, const torch::Tensor& target, const torch::Tensor& up);

// `frames` poses (frames,3,4), azimuth 2 pi k / frames for k = 0..frames-1, elevation clamped to
// +-kMaxElevationRad.
torch::Tensor camera_path(PathKind kind, int frames, const CameraRig& rig);

}  // namespace ablenerf
