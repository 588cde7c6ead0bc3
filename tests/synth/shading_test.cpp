// The tracer's geometry and shading against hand-computed values: camera rays, ray-sphere
// distances, mirror view dependence vs Lambertian view independence, glass Fresnel at normal
// incidence, sRGB encoding, and seed-driven camera placement.
#include <gtest/gtest.h>

#include <cmath>

#include "synth/scene.h"
#include "synth_test_util.h"

using namespace ablenerf::synth;
namespace st = ablenerf::synth_test;

namespace {

int index_of(MaterialKind k) {
  const auto& s = scene_spheres();
  for (size_t i = 0; i < s.size(); ++i)
    if (s[i].material == k) return static_cast<int>(i);
  return -1;
}

double max_abs_diff(const Vec3& a, const Vec3& b) {
  return std::max({std::abs(a.x - b.x), std::abs(a.y - b.y), std::abs(a.z - b.z)});
}

TEST(SynthCamera, RayDirectionFollowsTheLoaderConvention) {
  // Camera on -y looking at the origin: right = +x, up = +z, backwards = -y (hand-derived).
  const Camera cam = look_at_origin(Vec3{0, -4, 0}, 4);
  const double f = 0.5 * 4 / std::tan(0.5 * 0.6911112);
  EXPECT_NEAR(cam.focal, f, 1e-12);
  const Ray r = camera_ray(cam, 0.5, 0.5);  // pixel (0,0)'s centre: x = -1.5/f, y = +1.5/f, z = -1
  EXPECT_NEAR(r.dir.x, -1.5 / f, 1e-12);
  EXPECT_NEAR(r.dir.y, 1.0, 1e-12);
  EXPECT_NEAR(r.dir.z, 1.5 / f, 1e-12);
  EXPECT_NEAR(r.origin.y, -4.0, 1e-12);
  // The principal ray passes through the origin at t = 4 (t is depth along the optical axis).
  const Ray c = camera_ray(cam, 2.0, 2.0);
  EXPECT_NEAR(length(c.at(4.0)), 0.0, 1e-12);
}

TEST(SynthCamera, TrainViewsAreSeededAndCoverTheElevationBand) {
  const auto a = train_cameras(100, 8, 0), b = train_cameras(100, 8, 0), c = train_cameras(100, 8, 1);
  ASSERT_EQ(a.size(), 100u);
  double zmin = 1e9, zmax = -1e9, moved = 0;
  int east = 0;
  for (size_t k = 0; k < a.size(); ++k) {
    EXPECT_EQ(a[k].centre().x, b[k].centre().x);
    moved = std::max(moved, length(a[k].centre() - c[k].centre()));
    const double elev = std::asin(a[k].centre().z / 4.0) * 180.0 / M_PI;
    zmin = std::min(zmin, elev);
    zmax = std::max(zmax, elev);
    east += a[k].centre().x > 0;
  }
  EXPECT_GT(moved, 0.1);
  // The spiral spans the band [10, 80] degrees and both halves of the azimuth circle.
  EXPECT_LT(zmin, 12.0);
  EXPECT_GT(zmax, 75.0);
  EXPECT_GE(zmin, 10.0);
  EXPECT_LE(zmax, 80.0);
  EXPECT_GT(east, 35);
  EXPECT_LT(east, 65);
}

TEST(SynthGeometry, SphereDistanceMatchesClosedForm) {
  const Camera cam = look_at_origin(Vec3{2.0, -3.0, 1.5}, 64);
  for (const Sphere& s : scene_spheres()) {
    for (int j = 0; j < 64; j += 3)
      for (int i = 0; i < 64; i += 3) {
        const Ray r = camera_ray(cam, i + 0.5, j + 0.5);
        const double t = intersect_sphere(s, r, 0.0);
        const double ref = st::ray_sphere({r.origin.x, r.origin.y, r.origin.z}, {r.dir.x, r.dir.y, r.dir.z},
                                          {s.centre.x, s.centre.y, s.centre.z}, s.radius);
        if (ref < 0) {
          EXPECT_FALSE(std::isfinite(t));
        } else {
          EXPECT_NEAR(t, ref, 1e-9);
        }
      }
  }
  // From inside a sphere the exit distance is returned.
  const Sphere& s = scene_spheres()[0];
  EXPECT_NEAR(intersect_sphere(s, Ray{s.centre, Vec3{0, 0, 2}}, 0.0), s.radius / 2.0, 1e-12);
}

TEST(SynthShading, MirrorIsViewDependentAndDiffuseIsNot) {
  for (MaterialKind kind : {MaterialKind::Mirror, MaterialKind::Diffuse}) {
    const int idx = index_of(kind);
    ASSERT_GE(idx, 0);
    const Sphere& s = scene_spheres()[static_cast<size_t>(idx)];
    // A surface point facing slightly up and away from the z axis (away from the other spheres),
    // seen head-on (its reflection points into the coloured band just above the horizon) and
    // from 35 degrees higher (its reflection points below the horizon, at the ground).
    const Vec3 n = normalize(normalize(Vec3{s.centre.x, s.centre.y, 0.0}) + Vec3{0, 0, 0.3});
    const Vec3 p = s.centre + n * s.radius;
    const Vec3 up_tangent = normalize(Vec3{0, 0, 1} - n * n.z);
    Vec3 colours[2];
    for (int v = 0; v < 2; ++v) {
      const double ang = (v == 0 ? 0.0 : 35.0) * M_PI / 180.0;
      const Vec3 eye = p + (n * std::cos(ang) + up_tangent * std::sin(ang)) * 3.0;
      const Ray r{eye, p - eye};
      const Hit h = intersect_scene(r);
      ASSERT_EQ(h.object, idx);
      ASSERT_NEAR(h.t, 1.0, 1e-9);  // the first hit is p itself
      colours[v] = trace(r);
    }
    if (kind == MaterialKind::Mirror)
      EXPECT_GT(max_abs_diff(colours[0], colours[1]), 0.05) << "mirror reflection should change with the view";
    else
      EXPECT_LT(max_abs_diff(colours[0], colours[1]), 1e-12) << "Lambertian shading must not depend on the view";
  }
}

TEST(SynthShading, MirrorAtNormalIncidenceReflectsTheSkyTimesF0) {
  const Sphere& s = scene_spheres()[static_cast<size_t>(index_of(MaterialKind::Mirror))];
  // Straight down onto the top of the sphere: the reflection goes straight up into the sky.
  const Vec3 top = s.centre + Vec3{0, 0, s.radius};
  const Vec3 got = trace(Ray{top + Vec3{0, 0, 2}, Vec3{0, 0, -1}});
  const Vec3 want = mirror_f0() * environment(Vec3{0, 0, 1});
  EXPECT_LT(max_abs_diff(got, want), 1e-9);
}

TEST(SynthShading, GlassThroughTheCentreFollowsFresnelAndBeerLambert) {
  const Sphere& s = scene_spheres()[static_cast<size_t>(index_of(MaterialKind::Glass))];
  // A ray through the centre meets both surfaces at normal incidence: no bending, and
  // F = ((n-1)/(n+1))^2 = 0.04 for n = 1.5 (hand value).
  const double f = 0.04;
  const Vec3 d = normalize(Vec3{-0.3, -0.2, -1.0});  // leaves downwards, away from the other spheres
  const Ray r{s.centre - d * 3.0, d};
  ASSERT_EQ(intersect_scene(r).object, index_of(MaterialKind::Glass));
  const Vec3 a = glass_absorption();
  const double len = 2.0 * s.radius;
  const Vec3 att{std::exp(-a.x * len), std::exp(-a.y * len), std::exp(-a.z * len)};
  const Vec3 up = environment(-d), down = environment(d);
  // Front reflection + transmitted light with its internal back-and-forth geometric series.
  Vec3 want;
  for (int c = 0; c < 3; ++c) {
    const double A = att[c], series = 1.0 / (1.0 - f * f * A * A);
    const double v =
        f * up[c] + (1 - f) * (1 - f) * A * down[c] * series + (1 - f) * (1 - f) * f * A * A * up[c] * series;
    (c == 0 ? want.x : c == 1 ? want.y : want.z) = v;
  }
  const Vec3 got = trace(r);
  // The tracer drops branches below 1e-3 of the pixel: terms of order F^2 (1-F)^2 ~ 1.5e-3.
  EXPECT_LT(max_abs_diff(got, want), 3e-3) << got.x << " " << want.x;
  // And glass is not a mirror: most of what is seen comes from behind it.
  EXPECT_GT(max_abs_diff(got, f * up), 0.1);
}

TEST(SynthShading, EnvironmentHasSunSkyAndGroundAndMissesSeeIt) {
  EXPECT_LT(max_abs_diff(environment(sun_direction()), sun_radiance()), 1e-12);
  const Vec3 zenith = environment(Vec3{0, 0, 1}), nadir_ish = environment(normalize(Vec3{0.1, 0.1, -1}));
  EXPECT_GT(zenith.z, zenith.x);  // blue sky
  EXPECT_NE(max_abs_diff(zenith, nadir_ish), 0.0);
  // The coloured band: different azimuths at 10 degrees elevation differ in hue.
  const double e = 10.0 * M_PI / 180.0;
  const Vec3 b0 = environment(Vec3{std::cos(e), 0, std::sin(e)});
  const Vec3 b1 = environment(Vec3{-std::cos(e), 0, std::sin(e)});
  EXPECT_GT(max_abs_diff(b0, b1), 0.2);
  // A ray that misses everything returns the environment in its (normalised) direction.
  const Ray miss{Vec3{0, 0, 3}, Vec3{0, 0, 5}};
  ASSERT_FALSE(intersect_scene(miss).hit());
  EXPECT_LT(max_abs_diff(trace(miss), zenith), 1e-12);
}

TEST(SynthRender, SrgbEncodingAndRowThreadingIndependence) {
  EXPECT_DOUBLE_EQ(linear_to_srgb(0.0), 0.0);
  EXPECT_NEAR(linear_to_srgb(1.0), 1.0, 1e-12);
  EXPECT_NEAR(linear_to_srgb(0.002), 12.92 * 0.002, 1e-12);
  EXPECT_NEAR(linear_to_srgb(0.5), 0.735356983, 1e-6);  // published sRGB value for mid linear grey
  const Camera cam = look_at_origin(Vec3{1.0, -3.5, 1.6}, 24);
  const ViewImage a = render_view(cam, 1), b = render_view(cam, 3);
  EXPECT_EQ(a.rgba, b.rgba);
  EXPECT_EQ(a.depth, b.depth);
  // Soft edges: some pixels are partially covered (alpha strictly between 0 and 1), in 1/9 steps.
  int partial = 0;
  for (size_t p = 0; p < a.depth.size(); ++p) {
    const float al = a.rgba[p * 4 + 3];
    if (al > 0 && al < 1) ++partial;
    EXPECT_NEAR(al * 9.0, std::round(al * 9.0), 1e-5);
    if (a.depth[p] > 0) {
      EXPECT_GT(al, 0.0f);  // the centre sub-sample is the depth ray
    }
  }
  EXPECT_GT(partial, 10);
}

}  // namespace
