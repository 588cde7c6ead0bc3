#pragma once
// The [data] section of the run configuration (util/config_section.h), registered below: how a capture is read
// (data/dataset.h, data/scene_frame.h), owned by the data module.
#include <cmath>

#include "util/config_section.h"

namespace ablenerf {

enum class Background { White, Black };  // data.background: the colour RGBA images are composited on
// data.scene (data/scene_frame.h): where samples lie along a ray and how they are encoded.
//  * Bounded: depth-linear samples between near and far (Blender's object on a card);
//  * Unbounded: mip-NeRF 360's scene contraction of the frustum Gaussians, half the samples linear
//    in depth inside the cameras' sphere, half linear in disparity out to (practically) infinity;
//  * ForwardFacing: NeRF's normalised device coordinates (model/ndc.h) for captures whose cameras all
//    look the same way at a scene in front of them (LLFF): samples linear in disparity to infinity;
//  * Auto: Bounded for Blender scenes; for real captures ForwardFacing when every camera looks
//    within kForwardFacingMaxAngleDeg of their mean direction and the capture knows how near its
//    scene comes (sparse points or LLFF bounds), else Unbounded.
enum class SceneKind { Auto, Bounded, Unbounded, ForwardFacing };
// data.masks (data/dataset.h): which pixels of the photos train. Auto: the masks the capture comes
// with (a masks/ folder, nerfstudio's mask_path, instant-ngp's dynamic_mask_*), every pixel when it
// has none; None (the default): every pixel; Alpha: the pixels whose alpha is at least 0.5 (RGBA
// photos).
enum class MaskSource { Auto, None, Alpha };
// data.scene_centre (data/scene_frame.h): the point of a real capture that becomes the scene's origin,
// the centre of the contraction's unit sphere. Auto: what the cameras look at (the nearest point to
// their optical axes) when it lies in front of most of them, else the mean camera position; Focus
// and Cameras: one of the two whatever the layout (nerfstudio's "focus" and "poses").
enum class SceneCentre { Auto, Focus, Cameras };

template <>
inline const EnumNames<Background> kEnumNames<Background>{{Background::White, "white"}, {Background::Black, "black"}};
template <>
inline const EnumNames<SceneKind> kEnumNames<SceneKind>{{SceneKind::Auto, "auto"},
                                                        {SceneKind::Bounded, "bounded"},
                                                        {SceneKind::Unbounded, "unbounded"},
                                                        {SceneKind::ForwardFacing, "forward"}};
template <>
inline const EnumNames<SceneCentre> kEnumNames<SceneCentre>{
    {SceneCentre::Auto, "auto"}, {SceneCentre::Focus, "focus"}, {SceneCentre::Cameras, "cameras"}};
template <>
inline const EnumNames<MaskSource> kEnumNames<MaskSource>{
    {MaskSource::Auto, "auto"}, {MaskSource::None, "none"}, {MaskSource::Alpha, "alpha"}};

struct DataConfig {
  static constexpr const char* kName = "data";
  static constexpr int kOrder = 1;

  // Integer box-downscale factor; 0: chosen from the capture when training (train/image_size.h):
  // the finest reduction whose training pixels the run draws `auto_passes` times in its budget at
  // `auto_rays_per_s` (0: the speed measured when training starts), keeping at least
  // `auto_min_side` pixels on the short side.
  int downscale = 1;
  double auto_passes = 3.0;
  double auto_rays_per_s = 0;
  int auto_min_side = 64;
  Background background = Background::White;
  // Near/far of Blender scenes (their convention: 2/6). A real capture's bounds come from the
  // capture itself (sparse points, LLFF bounds or the camera layout; data/scene_frame.h) unless
  // bounds = "config".
  double near = 2.0;
  double far = 6.0;
  SceneKind scene = SceneKind::Auto;
  bool bounds_from_config = false;  // data.bounds_from_config: use near/far for captures too
  // data.ndc: whether `auto` may give a forward-facing capture NDC rays (data/scene_frame.h); false
  // contracts it as an unbounded scene, centred on what its cameras look at.
  bool ndc = true;
  // The scene frame of a real capture, chosen from the cameras unless set (data/scene_frame.h): its
  // centre, and its radius in the capture's units (the distance from the centre that becomes 1, the
  // contraction's unit sphere; 0: the farthest camera, or for cameras looking outward from inside a
  // room the median sparse point when farther). Either set keeps `auto` off NDC rays.
  SceneCentre scene_centre = SceneCentre::Auto;
  double scene_radius = 0;
  // Off by default: on the gold cape (object masks) training on the masked pixels only cost 0.8 dB
  // on the object at 15 minutes (docs/benchmarks/history.md, "The capture preset and the peer").
  MaskSource masks = MaskSource::None;

  template <class F>
  void visit(F&& f) {
    f("downscale", &downscale);
    f("auto_passes", &auto_passes);
    f("auto_rays_per_s", &auto_rays_per_s);
    f("auto_min_side", &auto_min_side);
    f("background", &background);
    f("near", &near);
    f("far", &far);
    f("scene", &scene);
    f("bounds_from_config", &bounds_from_config);
    f("ndc", &ndc);
    f("scene_centre", &scene_centre);
    f("scene_radius", &scene_radius);
    f("masks", &masks);
  }

  void validate(const SectionCheck& need) const {
    need(downscale >= 0, "downscale", "must be >= 1, or 0 to choose from the capture");
    need(auto_passes > 0 && std::isfinite(auto_passes), "auto_passes", "must be > 0");
    need(auto_rays_per_s >= 0 && std::isfinite(auto_rays_per_s), "auto_rays_per_s", "must be >= 0 (0: measured)");
    need(auto_min_side >= 1, "auto_min_side", "must be >= 1");
    need(near >= 0 && far > near, "far", "need 0 <= near < far");
    need(scene_radius >= 0 && std::isfinite(scene_radius), "scene_radius",
         "must be > 0 (the capture's units), or 0 to choose from the cameras");
  }
};
ABLENERF_CONFIG_SECTION(DataConfig);

}  // namespace ablenerf
