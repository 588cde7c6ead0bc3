#pragma once
// Supersampled rendering of one view of a synth scene (the demo's spheres or the room, through
// their SceneTracer): straight-alpha sRGB RGBA plus the exact optical-axis depth of each pixel's
// centre ray.
#include <cstdint>
#include <vector>

#include "synth/camera.h"

namespace ablenerf::synth {

// Sub-samples per pixel side on a fixed grid at offsets (k + 0.5) / n. With an odd n the middle
// sub-sample is the pixel centre, so a pixel with depth > 0 always has alpha > 0.
constexpr int kSubsamplesPerAxis = 3;

struct ViewImage {
  int width = 0, height = 0;
  // Row-major (H, W, 4): sRGB-encoded colour in [0,1] averaged (in linear space) over the
  // sub-samples that hit an object, then alpha = the fraction that hit. RGB = 0 where alpha = 0.
  std::vector<float> rgba;
  // Row-major (H, W): t of the pixel-centre ray's first hit (= camera-space -z), 0 on a miss.
  std::vector<float> depth;
  // Row-major (H, W), with a distractor only: 1 where some sub-sample saw it, else 0.
  std::vector<uint8_t> distractor;
};

// A photo's distractor (`synth --distractor`): a ball of one flat colour in front of the scene, seen
// by that photo alone (a passer-by). It casts no shadow and nothing reflects it.
struct Distractor {
  Vec3 centre;
  double radius = 0;
};
// Its colour, linear: a magenta that nothing in the demo scene has.
inline Vec3 distractor_colour() { return {0.9, 0.02, 0.7}; }

// Renders with `threads` workers over rows (<= 0: hardware concurrency). The result does not
// depend on the thread count: every pixel is computed independently. With
// `environment_background` a sub-sample that misses every object sees the environment (sky and
// ground at infinity) and counts as a hit: alpha is 1 everywhere, depth stays 0 on a miss.
// `gain` multiplies the linear radiance of every sub-sample before the film clamps it (a photo's
// exposure and white balance).
// `distractor`, when given, hides whatever lies behind it (ViewImage::distractor marks its pixels).
// `scene` is what is rendered: the demo's spheres (world.h) unless told otherwise, or the room
// (room.h), whose walls every ray meets, so that its views are opaque without a background.
ViewImage render_view(const Camera& cam, int threads = 1, bool environment_background = false,
                      const Vec3& gain = {1, 1, 1}, const Distractor* distractor = nullptr,
                      const SceneTracer& scene = demo_tracer());

// IEC 61966-2-1 sRGB transfer function for a linear value in [0,1].
double linear_to_srgb(double linear);

}  // namespace ablenerf::synth
