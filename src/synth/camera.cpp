#include "synth/camera.h"

#include <cmath>
#include <random>

namespace ablenerf::synth {

namespace {

constexpr double kDeg = M_PI / 180.0;
// The golden angle as a fraction of a turn: (3 - sqrt 5) / 2 gives the most even spiral.
const double kGoldenTurn = 0.5 * (3.0 - std::sqrt(5.0));
// Test orbit starts facing the -y side of the scene (azimuth -90 degrees).
constexpr double kTestStartAzimuthDeg = -90.0;

Vec3 spherical(double elevation, double azimuth) {
  return Vec3{std::cos(elevation) * std::cos(azimuth), std::cos(elevation) * std::sin(azimuth), std::sin(elevation)} *
         kCameraDistance;
}

}  // namespace

double focal_from_angle(int width, double angle_x) { return 0.5 * width / std::tan(0.5 * angle_x); }

Camera upright_camera(const Vec3& centre, const Vec3& back, int res, double angle_x) {
  const Vec3 right = normalize(cross(Vec3{0, 0, 1}, back));  // horizontal: no roll
  const Vec3 up = cross(back, right);
  Camera cam;
  const Vec3 cols[4] = {right, up, back, centre};
  for (int c = 0; c < 4; ++c) {
    cam.c2w[0][c] = cols[c].x;
    cam.c2w[1][c] = cols[c].y;
    cam.c2w[2][c] = cols[c].z;
  }
  cam.width = cam.height = res;
  cam.focal = focal_from_angle(res, angle_x);
  return cam;
}

Camera look_at_origin(const Vec3& centre, int res) {
  return upright_camera(centre, normalize(centre), res, kCameraAngleX);  // z: from the origin to the camera
}

void distort_point(const SynthLens& l, double x, double y, double& xd, double& yd) {
  const double r2 = x * x + y * y, radial = 1 + l.k1 * r2 + l.k2 * r2 * r2;
  xd = x * radial + 2 * l.p1 * x * y + l.p2 * (r2 + 2 * x * x);
  yd = y * radial + l.p1 * (r2 + 2 * y * y) + 2 * l.p2 * x * y;
}

void undistort_point(const SynthLens& l, double xd, double yd, double& x, double& y) {
  x = xd, y = yd;
  for (int it = 0; it < 100; ++it) {
    const double r2 = x * x + y * y, radial = 1 + l.k1 * r2 + l.k2 * r2 * r2;
    const double dx = 2 * l.p1 * x * y + l.p2 * (r2 + 2 * x * x), dy = l.p1 * (r2 + 2 * y * y) + 2 * l.p2 * x * y;
    const double nx = (xd - dx) / radial, ny = (yd - dy) / radial;
    const bool done = std::abs(nx - x) < 1e-15 && std::abs(ny - y) < 1e-15;
    x = nx, y = ny;
    if (done) break;
  }
}

Ray camera_ray(const Camera& cam, double px, double py) {
  double x = (px - 0.5 * cam.width) / cam.focal;
  double y = (py - 0.5 * cam.height) / cam.focal;  // down
  if (cam.lens.distorted()) undistort_point(cam.lens, x, y, x, y);
  const Vec3 d = cam.axis(0) * x - cam.axis(1) * y - cam.axis(2);
  return {cam.centre(), d};
}

std::vector<Camera> train_cameras(int count, int res, uint64_t seed) {
  std::mt19937_64 rng(seed);
  const double stratum_offset = unit_uniform(rng);
  const double rotation = unit_uniform(rng);
  // Uniform by area on the band: sin(elevation) uniform between the band's limits.
  const double z_lo = std::sin(kMinElevationDeg * kDeg), z_hi = std::sin(kMaxElevationDeg * kDeg);
  std::vector<Camera> cams;
  cams.reserve(static_cast<size_t>(count));
  for (int k = 0; k < count; ++k) {
    const double z = z_lo + (z_hi - z_lo) * (k + stratum_offset) / count;
    const double turn = k * kGoldenTurn + rotation;
    const double azimuth = 2.0 * M_PI * (turn - std::floor(turn));
    cams.push_back(look_at_origin(spherical(std::asin(z), azimuth), res));
  }
  return cams;
}

std::vector<Camera> test_cameras(int count, int res) {
  std::vector<Camera> cams;
  cams.reserve(static_cast<size_t>(count));
  for (int k = 0; k < count; ++k) {
    const double azimuth = kTestStartAzimuthDeg * kDeg + 2.0 * M_PI * k / count;
    cams.push_back(look_at_origin(spherical(kTestElevationDeg * kDeg, azimuth), res));
  }
  return cams;
}

}  // namespace ablenerf::synth
