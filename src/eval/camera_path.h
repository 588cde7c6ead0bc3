#pragma once
// Camera paths for `ablenerf render`: an orbit (circle around the world z axis) or a spiral
// (the orbit with the elevation oscillating), every camera looking at the origin with +z up.
// Both stay where the training cameras were: when the cameras leave a gap of more than
// kOpenArcGapRad in azimuth (a capture that did not go all the way round), the path sweeps the
// covered arc out and back instead of circling through the gap; the spiral's swing stays inside
// the cameras' elevation range.
// Poses are camera-to-world (3,4) in the Blender/OpenGL convention (see data/rays.h): camera x
// right, y up, and the camera looks along its -z axis.
#include <torch/torch.h>

#include <cmath>
#include <string>

namespace ablenerf {

enum class PathKind { Orbit, Spiral };

// "orbit" / "spiral"; throws InputError(source, field, ...) otherwise.
PathKind parse_path_kind(const std::string& name, const std::string& source = "--path", const std::string& field = "");

// Where the training cameras sit, seen from the origin.
struct CameraRig {
  double distance = 4.0;   // mean distance of the camera centres from the origin
  double elevation = 0.5;  // mean elevation angle above the xy plane, radians
  // The azimuth arc the cameras cover (radians, counter-clockwise from +x): the whole circle, or
  // from `azimuth_start` over `azimuth_span` < 2 pi.
  double azimuth_start = 0.0;
  double azimuth_span = 2 * M_PI;
  // The cameras' elevation range, radians.
  double elevation_min = -M_PI / 2, elevation_max = M_PI / 2;
  bool full_circle() const { return azimuth_span >= 2 * M_PI; }
};
// The largest azimuth gap between neighbouring cameras that still counts as going all the way round.
constexpr double kOpenArcGapRad = M_PI / 2;
// From (N,3,4) or (N,4,4) poses.
CameraRig camera_rig(const torch::Tensor& c2w);

// Largest |elevation| a path may reach: looking straight down the z axis makes "+z up" undefined.
constexpr double kMaxElevationRad = 1.4835298641951802;  // 85 degrees
// Half the peak-to-peak elevation swing of the spiral, radians (15 degrees).
constexpr double kSpiralAmplitudeRad = 0.2617993877991494;
// Full elevation oscillations of the spiral over one turn of azimuth.
constexpr int kSpiralCycles = 2;

// A camera at `eye` looking at `target` with the world `up` direction (float (3,4)): the one
// look-at of the tensor code (render paths, the viewer, `bench`'s views). The demo scene's ray
// tracer keeps its own on its plain vectors (synth/camera.h), as synth stands apart from LibTorch.
// Throws std::invalid_argument when eye == target or the view direction is parallel to `up`.
torch::Tensor look_at(const torch::Tensor& eye, const torch::Tensor& target, const torch::Tensor& up);

// `frames` poses (frames,3,4), elevation clamped to +-kMaxElevationRad. Azimuth 2 pi k / frames for
// k = 0..frames-1 on a full circle; on an arc start + span (1 - cos(2 pi k / frames)) / 2 (out to
// the arc's far end at mid-video and back, easing at both ends, so the video loops). The spiral's
// swing is kSpiralAmplitudeRad or less, to stay inside [elevation_min, elevation_max].
torch::Tensor camera_path(PathKind kind, int frames, const CameraRig& rig);

// A camera path recorded in the viewer (`ablenerf view`, "record"): JSON
//   {"ablenerf_path": 1, "coordinates": "scene", "poses": [[12 numbers: row-major 3x4
//    camera-to-world in the run's scene frame], ...]}
// Returns (N,3,4) float poses. InputError(path, field, ...) on anything else: not JSON, another
// version or coordinate frame, no poses, a pose that is not 12 finite numbers or not a rotation.
torch::Tensor read_path_file(const std::string& path);
// Whether --path names such a file rather than orbit / spiral.
bool is_path_file(const std::string& name);

// Forward-facing scenes (data.scene = "forward": cameras near z = 0 looking down -z, the nearest
// content at 1 / 0.75 in front): LLFF's path. The eye goes round an ellipse in the cameras' plane
// whose half-axes are the largest |x| and |y| of the camera centres (`c2w`, (N,3,4)), looking at
// (0, 0, -kForwardFocusDepth) with +y up; the spiral also moves it forward and back by half the
// smaller half-axis, twice per turn.
constexpr double kForwardFocusDepth = 4.0 / 0.75;  // LLFF: 1 / (0.25 / nearest + 0.75 / infinity)
torch::Tensor forward_facing_path(PathKind kind, int frames, const torch::Tensor& c2w);

}  // namespace ablenerf
