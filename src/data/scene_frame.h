#pragma once
// Scene normalisation of a real capture (torch-free): captures come in arbitrary units, origin and
// orientation. The scene frame maps capture coordinates to the model's working volume:
//   x_scene = scale * R (x_capture - centre),
// with R turning the cameras' mean up vector to +z, the centre the point the cameras look at
// (least-squares nearest point to their optical axes, when it lies in front of most of them; else
// the mean camera position) and the scale putting the farthest camera at distance 1 (for cameras
// looking outward from inside a room, the farther of it and the median sparse point). Near/far
// come from what the capture knows: its sparse points (COLMAP), its per-image bounds (LLFF), else
// the camera layout. Blender scenes keep the identity and their 2/6.
#include <array>
#include <string>
#include <vector>

#include "data/capture.h"
#include "data/data_config.h"

namespace ablenerf {

struct SceneFrame {
  std::array<double, 9> rotation{1, 0, 0, 0, 1, 0, 0, 0, 1};  // row-major R
  std::array<double, 3> centre{0, 0, 0};
  double scale = 1;
  SceneKind kind = SceneKind::Bounded;  // resolved: Bounded, Unbounded or ForwardFacing
  double near = 2, far = 6;             // in scene units (ForwardFacing: 0 and 1, the NDC ray's t)
  // ForwardFacing: the NDC projection's focal factors 2 fx / W and 2 fy / H (model/ndc.h).
  double ndc_a = 0, ndc_b = 0;
  std::string bounds_source = "config";  // "points" | "llff bounds" | "cameras" | "config"
  // The cameras' layout, whatever the kind: every optical axis within kForwardFacingMaxAngleDeg of
  // their mean (LLFF's captures; true for every ForwardFacing scene). A forward-facing capture
  // contracted as an unbounded scene (data.ndc = false) keeps it, for the settings that depend on
  // the layout rather than on the ray parametrisation (train.distortion_forward_facing).
  bool faces_one_way = false;
  // Cameras that look at no common region and not all one way: they look out at what surrounds
  // them (a room photographed from inside). The scale then puts the median sparse point, not the
  // farthest camera, at distance 1 (when the capture has sparse points).
  bool looks_outward = false;
  // Why the centre and the radius are what they are (`info`, the run's scene.json): "focus" (what
  // the cameras look at), "cameras" (their mean position), with " (data.scene_centre)" when the config
  // chose it; "farthest camera", "median sparse point" or "data.scene_radius". Empty for Blender
  // scenes and forward-facing frames.
  std::string centre_source, radius_source;

  bool identity() const;
  // A camera-to-world pose in capture coordinates -> scene coordinates (and back).
  Pose34 to_scene(const Pose34& c2w) const;
  Pose34 to_capture(const Pose34& c2w) const;
  std::array<double, 3> point_to_scene(const std::array<double, 3>& p) const;

  std::string to_json() const;  // RUN/scene.json
  // Parses to_json's text; InputError(origin, field, ...) on anything else.
  static SceneFrame from_json(const std::string& text, const std::string& origin);
  // One line for logs and `info`.
  std::string describe() const;
};

// Forward-facing layouts: every camera's optical axis within this angle of their mean.
constexpr double kForwardFacingMaxAngleDeg = 35.0;
// Forward-facing scenes are scaled so that the nearest content (1st percentile of the sparse
// points' depths, or the smallest LLFF near bound) sits at 1 / kForwardNearFraction in front of the
// cameras, beyond the NDC near plane at 1 (LLFF's convention).
constexpr double kForwardNearFraction = 0.75;

// Unbounded scenes: the far bound (scene units). Samples reach it linearly in disparity, and the
// contraction maps everything beyond the unit sphere into radius 2, so it stands for infinity.
constexpr double kUnboundedFar = 1e6;

// The config's say in a real capture's frame (data.scene_centre, data.scene_radius in the capture's
// units, 0 = chosen).
struct SceneFrameOverrides {
  SceneCentre centre = SceneCentre::Auto;
  double radius = 0;
  bool any() const { return centre != SceneCentre::Auto || radius > 0; }
};

// Fits the scene frame of a capture from all of its frames (every split: training and evaluation
// must share one frame). Forward-facing captures get another frame: centred on the mean camera,
// rotated so that the cameras look down -z with their mean up towards +y, scaled by
// kForwardNearFraction (model/ndc.h); `auto` picks it when the layout is forward-facing and the
// capture has sparse points or LLFF bounds (and `auto_ndc`, data.ndc, allows it: without, such a
// capture is fitted as an unbounded one), and `forward` without either is refused. `requested`
// is data.scene; `near`/`far` are data.near/data.far, used for Blender scenes and, with
// `bounds_from_config`, for every capture; `overrides` the centre and radius (an override keeps `auto`
// off NDC rays; refused for Blender scenes and `forward`, whose frames are fixed). InputError(root,
// "poses", ...) for degenerate layouts (all cameras at one point).
SceneFrame fit_scene_frame(const Capture& capture, const std::string& root, SceneKind requested, double near,
                           double far, bool bounds_from_config, bool auto_ndc = true,
                           const SceneFrameOverrides& overrides = {});

}  // namespace ablenerf
