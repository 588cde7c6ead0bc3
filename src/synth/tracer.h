#pragma once
// What the renderer (render.h) needs of a synth scene, whichever it is: rays, the first hit along a
// ray and the radiance arriving along it. The demo scene (world.h) and the room (room.h) each
// provide a SceneTracer; render_view takes one, so both share the film, the sub-sampling, the
// depth convention and the writer (scene.h).
#include <limits>

#include "util/vec3.h"

namespace ablenerf::synth {

// A ray o + t d; d need not be unit length (t is then in units of |d|).
struct Ray {
  Vec3 origin, dir;
  Vec3 at(double t) const { return origin + dir * t; }
};

struct Hit {
  double t = std::numeric_limits<double>::infinity();
  int object = -1;  // index into the scene's objects (scene_spheres(), room_objects()), -1 = miss
  bool hit() const { return object >= 0; }
};

// A scene as the renderer sees it. Both functions are pure (deterministic, thread-safe).
struct SceneTracer {
  // The first object along the ray (t > t_min); its t, in units of |r.dir|, is the pixel's depth.
  Hit (*intersect)(const Ray& r, double t_min);
  // Linear radiance arriving along the ray (depth: recursion depth, 0 for a primary ray).
  Vec3 (*trace)(const Ray& r, int depth);
};

}  // namespace ablenerf::synth
