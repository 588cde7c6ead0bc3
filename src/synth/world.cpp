#include "synth/world.h"

#include <algorithm>
#include <cmath>

namespace ablenerf::synth {

namespace {

// Secondary rays start this far off the surface so they do not re-hit it through round-off.
constexpr double kSurfaceOffset = 1e-7;
// Branches whose contribution to the pixel is below this are dropped (keeps glass cheap).
constexpr double kMinThroughput = 1e-3;

// Sky: zenith/horizon gradient, a coloured band just above the horizon whose hue turns with
// azimuth (so mirror and glass reflections change visibly with the viewpoint), and the sun.
constexpr Vec3 kZenith{0.18, 0.34, 0.85};
constexpr Vec3 kHorizon{0.80, 0.86, 0.95};
constexpr double kBandLowDeg = 3.0, kBandHighDeg = 22.0;  // elevation range of the coloured band
constexpr double kBandStrength = 0.75;
constexpr int kBandHueCycles = 3;  // hue cycles per full turn of azimuth
constexpr Vec3 kSunGlow{1.2, 0.9, 0.5};
constexpr double kSunGlowExponent = 48.0;
// Ground: a checkerboard on the plane z = -kGroundDepth, fading into haze towards the horizon.
constexpr double kGroundDepth = 1.5;
constexpr double kGroundCell = 1.0;
constexpr Vec3 kGroundA{0.42, 0.34, 0.24}, kGroundB{0.10, 0.16, 0.10}, kGroundHaze{0.45, 0.45, 0.42};
constexpr double kHazeRate = 0.06;  // per unit of distance along the ground
// Diffuse sphere checker: cells in longitude x latitude.
constexpr int kCheckerLon = 12, kCheckerLat = 6;
constexpr Vec3 kAlbedoA{0.75, 0.12, 0.08}, kAlbedoB{0.85, 0.80, 0.62};

// Average sky and ground radiance, used as a hemispherical ambient term for the diffuse sphere
// (the irradiance of a two-colour sky/ground dome, blended by the normal's z).
constexpr Vec3 kAmbientSky{0.45, 0.55, 0.80}, kAmbientGround{0.25, 0.22, 0.17};

double smoothstep(double e0, double e1, double x) {
  const double t = std::clamp((x - e0) / (e1 - e0), 0.0, 1.0);
  return t * t * (3.0 - 2.0 * t);
}

// Fraction of the sun's light reaching p (shadow ray towards the sun).
double sun_visibility(const Vec3& p) {
  const Ray shadow{p, sun_direction()};
  double vis = 1.0;
  for (const Sphere& s : scene_spheres()) {
    if (!std::isfinite(intersect_sphere(s, shadow, 0.0))) continue;
    if (s.material != MaterialKind::Glass) return 0.0;
    vis *= kGlassShadowTransmittance;
  }
  return vis;
}

Vec3 shade_diffuse(const Vec3& p, const Vec3& n) {
  const Vec3 albedo = diffuse_albedo(n);
  const double cos_sun = std::max(0.0, dot(n, sun_direction()));
  const Vec3 direct =
      cos_sun > 0 ? sun_irradiance() * (cos_sun * sun_visibility(p + n * kSurfaceOffset) / M_PI) : Vec3{};
  const Vec3 ambient = mix(kAmbientGround, kAmbientSky, 0.5 * (1.0 + n.z));
  return albedo * (direct + ambient);
}

// Exact Fresnel reflectance of an unpolarised ray at a dielectric interface.
// cos_i: cosine of the incidence angle (> 0); eta = n_incident / n_transmitted.
// Returns 1 for total internal reflection and sets cos_t otherwise.
double fresnel_dielectric(double cos_i, double eta, double& cos_t) {
  const double sin2_t = eta * eta * std::max(0.0, 1.0 - cos_i * cos_i);
  if (sin2_t >= 1.0) {
    cos_t = 0.0;
    return 1.0;
  }
  cos_t = std::sqrt(1.0 - sin2_t);
  const double rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
  const double rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
  return 0.5 * (rs * rs + rp * rp);
}

Vec3 trace_weighted(const Ray& r, int depth, double weight);

Vec3 shade_mirror(const Vec3& p, const Vec3& n, const Vec3& d, int depth, double weight) {
  // Schlick's approximation for a metal: reflectance rises towards 1 at grazing angles.
  const double c = std::clamp(-dot(d, n), 0.0, 1.0);
  const double k = std::pow(1.0 - c, 5.0);
  const Vec3 f = mirror_f0() + (Vec3{1, 1, 1} - mirror_f0()) * k;
  const Vec3 out = reflect(d, n);
  const double w = weight * std::max({f.x, f.y, f.z});
  return f * trace_weighted(Ray{p + n * kSurfaceOffset, out}, depth + 1, w);
}

Vec3 shade_glass(const Vec3& p, const Vec3& n, const Vec3& d, double seg_len, int depth, double weight) {
  const bool entering = dot(d, n) < 0.0;
  const Vec3 nf = entering ? n : -n;  // normal on the incident side
  const double eta = entering ? 1.0 / kGlassIor : kGlassIor;
  const double cos_i = -dot(d, nf);
  double cos_t = 0.0;
  const double f = fresnel_dielectric(cos_i, eta, cos_t);
  Vec3 result;
  if (f > 0.0 && weight * f >= kMinThroughput)
    result += trace_weighted(Ray{p + nf * kSurfaceOffset, reflect(d, nf)}, depth + 1, weight * f) * f;
  if (f < 1.0 && weight * (1.0 - f) >= kMinThroughput) {
    const Vec3 t = d * eta + nf * (eta * cos_i - cos_t);
    result += trace_weighted(Ray{p - nf * kSurfaceOffset, t}, depth + 1, weight * (1.0 - f)) * (1.0 - f);
  }
  // A ray leaving the glass travelled seg_len inside it: Beer-Lambert tint.
  if (!entering) {
    const Vec3 a = glass_absorption();
    result = result * Vec3{std::exp(-a.x * seg_len), std::exp(-a.y * seg_len), std::exp(-a.z * seg_len)};
  }
  return result;
}

Vec3 trace_weighted(const Ray& r, int depth, double weight) {
  const Vec3 d = normalize(r.dir);
  if (depth >= kMaxBounces) return environment(d);
  const Hit h = intersect_scene(r, 0.0);
  if (!h.hit()) return environment(d);
  const Sphere& s = scene_spheres()[static_cast<size_t>(h.object)];
  const Vec3 p = r.at(h.t);
  const Vec3 n = (p - s.centre) / s.radius;
  switch (s.material) {
    case MaterialKind::Diffuse: return shade_diffuse(p, n);
    case MaterialKind::Mirror: return shade_mirror(p, n, d, depth, weight);
    case MaterialKind::Glass: return shade_glass(p, n, d, h.t * length(r.dir), depth, weight);
  }
  return {};
}

}  // namespace

const char* material_name(MaterialKind k) {
  switch (k) {
    case MaterialKind::Diffuse: return "diffuse";
    case MaterialKind::Mirror: return "mirror";
    case MaterialKind::Glass: return "glass";
  }
  return "?";
}

const std::vector<Sphere>& scene_spheres() {
  // Three spheres on a circle of radius ~0.72 around the z axis, 120 degrees apart, so that
  // each one reflects or refracts the others from some viewpoints.
  static const std::vector<Sphere> spheres = {
      {"mirror_sphere", MaterialKind::Mirror, {0.0, 0.72, 0.10}, 0.48},
      {"glass_sphere", MaterialKind::Glass, {-0.6235, -0.36, 0.0}, 0.45},
      {"diffuse_sphere", MaterialKind::Diffuse, {0.6235, -0.36, -0.05}, 0.45},
  };
  return spheres;
}

Vec3 sun_direction() { return normalize(Vec3{0.45, -0.30, 0.84}); }
Vec3 sun_irradiance() { return {3.2, 2.9, 2.5}; }
Vec3 sun_radiance() { return {60.0, 55.0, 45.0}; }
Vec3 mirror_f0() { return {0.93, 0.90, 0.84}; }
Vec3 glass_absorption() { return {0.30, 0.06, 0.18}; }

double intersect_sphere(const Sphere& s, const Ray& r, double t_min) {
  // |o + t d - c|^2 = r^2  ->  a t^2 + 2 h t + c0 = 0 with the half-b form for accuracy.
  const Vec3 oc = r.origin - s.centre;
  const double a = dot(r.dir, r.dir);
  const double h = dot(r.dir, oc);
  const double c0 = dot(oc, oc) - s.radius * s.radius;
  const double disc = h * h - a * c0;
  if (disc < 0.0) return std::numeric_limits<double>::infinity();
  const double root = std::sqrt(disc);
  const double t_near = (-h - root) / a;
  if (t_near > t_min) return t_near;
  const double t_far = (-h + root) / a;
  if (t_far > t_min) return t_far;
  return std::numeric_limits<double>::infinity();
}

Hit intersect_scene(const Ray& r, double t_min) {
  Hit best;
  const auto& spheres = scene_spheres();
  for (size_t i = 0; i < spheres.size(); ++i) {
    const double t = intersect_sphere(spheres[i], r, t_min);
    if (t < best.t) {
      best.t = t;
      best.object = static_cast<int>(i);
    }
  }
  return best;
}

Vec3 environment(const Vec3& d) {
  const Vec3 sun = sun_direction();
  const double cos_sun = dot(d, sun);
  if (cos_sun >= std::cos(kSunAngularRadiusDeg * M_PI / 180.0)) return sun_radiance();
  const Vec3 glow = kSunGlow * std::pow(std::max(0.0, cos_sun), kSunGlowExponent);
  if (d.z >= 0.0) {
    const double elev_deg = std::asin(std::min(1.0, d.z)) * 180.0 / M_PI;
    Vec3 sky = mix(kHorizon, kZenith, std::sqrt(d.z));
    // Band weight: a smooth bump over [kBandLowDeg, kBandHighDeg].
    const double band = smoothstep(kBandLowDeg, kBandLowDeg + 4.0, elev_deg) *
                        (1.0 - smoothstep(kBandHighDeg - 6.0, kBandHighDeg, elev_deg));
    if (band > 0.0) {
      const double phi = std::atan2(d.y, d.x) * kBandHueCycles;
      const Vec3 hue{0.5 + 0.5 * std::cos(phi), 0.5 + 0.5 * std::cos(phi - 2.0 * M_PI / 3.0),
                     0.5 + 0.5 * std::cos(phi + 2.0 * M_PI / 3.0)};
      sky = mix(sky, hue, band * kBandStrength);
    }
    return sky + glow;
  }
  // Below the horizon: where the direction meets the ground plane z = -kGroundDepth.
  const double dist = kGroundDepth / -d.z;
  const double gx = d.x * dist / kGroundCell, gy = d.y * dist / kGroundCell;
  const bool odd = (static_cast<long long>(std::floor(gx)) + static_cast<long long>(std::floor(gy))) & 1LL;
  const Vec3 ground = odd ? kGroundA : kGroundB;
  return mix(kGroundHaze, ground, std::exp(-kHazeRate * dist)) + glow * 0.2;
}

Vec3 diffuse_albedo(const Vec3& n) {
  const double u = (std::atan2(n.y, n.x) + M_PI) / (2.0 * M_PI);  // longitude in [0,1]
  const double v = std::acos(std::clamp(n.z, -1.0, 1.0)) / M_PI;  // colatitude in [0,1]
  const int iu = std::min(kCheckerLon - 1, static_cast<int>(u * kCheckerLon));
  const int iv = std::min(kCheckerLat - 1, static_cast<int>(v * kCheckerLat));
  return ((iu + iv) & 1) ? kAlbedoA : kAlbedoB;
}

Vec3 trace(const Ray& r, int depth) { return trace_weighted(r, depth, 1.0); }

SceneTracer demo_tracer() { return {&intersect_scene, &trace}; }

}  // namespace ablenerf::synth
