#pragma once
// The demo scene's content: three spheres (diffuse checker, mirror, glass) lit by a procedural
// environment and one directional "sun", and the recursive ray tracer that shades them. All
// radiance values are linear; clamping and sRGB encoding happen in render.cpp.
#include <vector>

#include "synth/tracer.h"
#include "util/vec3.h"

namespace ablenerf::synth {

enum class MaterialKind { Diffuse, Mirror, Glass };
const char* material_name(MaterialKind k);

struct Sphere {
  const char* name;
  MaterialKind material;
  Vec3 centre;
  double radius;
};

// The fixed scene: every sphere lies inside the ball of radius kSceneBound around the origin.
const std::vector<Sphere>& scene_spheres();
constexpr double kSceneBound = 1.3;

// Material and lighting constants (also written to scene.json).
constexpr double kGlassIor = 1.5;
constexpr int kMaxBounces = 6;                     // reflection/refraction depth before falling back to the sky
constexpr double kSunAngularRadiusDeg = 2.5;       // visible disc in the environment
constexpr double kGlassShadowTransmittance = 0.6;  // cheap stand-in for light through glass (no caustics)
Vec3 sun_direction();                              // unit vector towards the sun (upper hemisphere)
Vec3 sun_irradiance();                             // directional light's irradiance on a surface facing it
Vec3 sun_radiance();                               // radiance of the visible sun disc
Vec3 mirror_f0();         // mirror reflectance at normal incidence (Schlick towards 1 at grazing)
Vec3 glass_absorption();  // Beer-Lambert coefficients per unit length inside the glass

// Smallest t > t_min at which the ray meets the sphere, or +infinity.
double intersect_sphere(const Sphere& s, const Ray& r, double t_min);
// The first object along the ray (t > t_min).
Hit intersect_scene(const Ray& r, double t_min = 0.0);

// Environment radiance seen along a unit direction: sky gradient, coloured band above the
// horizon, a sun disc with a glow, and a checkered ground below the horizon.
Vec3 environment(const Vec3& unit_dir);

// Albedo of the diffuse sphere at a unit normal (in the sphere's frame): a checker pattern.
Vec3 diffuse_albedo(const Vec3& unit_normal);

// Radiance arriving along the ray (from the first hit, or the environment on a miss).
Vec3 trace(const Ray& r, int depth = 0);

// intersect_scene and trace, for render_view.
SceneTracer demo_tracer();

}  // namespace ablenerf::synth
