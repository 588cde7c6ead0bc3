#pragma once
// Cameras of the demo dataset: Blender/OpenGL camera-to-world poses on the upper hemisphere,
// looking at the origin, and primary rays generated exactly like src/data/rays.h does.
#include <cstdint>
#include <random>
#include <vector>

#include "util/vec3.h"
#include "synth/world.h"

namespace ablenerf::synth {

constexpr double kCameraAngleX = 0.6911112;  // Blender lego's horizontal field of view
constexpr double kCameraDistance = 4.0;
constexpr double kMinElevationDeg = 10.0, kMaxElevationDeg = 80.0;  // train views
constexpr double kTestElevationDeg = 30.0;                          // test orbit

// The variant's lens (`ablenerf synth --lens opencv`): OpenCV radial-tangential distortion of the
// normalised image point, x_d = x (1 + k1 r^2 + k2 r^4) + 2 p1 x y + p2 (r^2 + 2 x^2) (y likewise,
// y pointing down), barrel-shaped like an action camera's wide lens: the corners move inwards by
// ~7.6% of their distance from the centre (2.6 pixels of a 48x48 view).
struct SynthLens {
  double k1 = 0, k2 = 0, p1 = 0, p2 = 0;
  bool distorted() const { return k1 != 0 || k2 != 0 || p1 != 0 || p2 != 0; }
};
constexpr SynthLens kWideLens{-0.32, 0.11, 0.002, -0.0015};

// The distorted point of the normalised point (x, y).
void distort_point(const SynthLens& lens, double x, double y, double& xd, double& yd);
// Its inverse by OpenCV's fixed-point iteration (cv::undistortPoints; ablenerf's own loader uses
// Newton's method, src/data/lens_radial_tangential.cpp): converged to 1e-15 or 100 iterations.
void undistort_point(const SynthLens& lens, double xd, double yd, double& x, double& y);

struct Camera {
  // Camera-to-world (3 rows of 4): columns are camera right, up, backwards (it looks down -z),
  // and the camera centre.
  double c2w[3][4] = {{0}};
  int width = 0, height = 0;
  double focal = 1.0;  // pixels; fx = fy, principal point at the image centre
  SynthLens lens;      // none by default (a pinhole)
  Vec3 centre() const { return {c2w[0][3], c2w[1][3], c2w[2][3]}; }
  Vec3 axis(int col) const { return {c2w[0][col], c2w[1][col], c2w[2][col]}; }
};

// A uniform double in [0,1) from the top 53 bits: identical on every standard library, unlike
// std::uniform_real_distribution (the camera layouts' draws).
inline double unit_uniform(std::mt19937_64& rng) { return static_cast<double>(rng() >> 11) * 0x1.0p-53; }

// f = 0.5 W / tan(0.5 angle_x).
double focal_from_angle(int width, double angle_x);

// A square res x res camera at `centre` whose backward axis (camera z) is the unit vector `back`, its
// right axis horizontal (no roll, +z as the up hint), with horizontal field of view angle_x.
Camera upright_camera(const Vec3& centre, const Vec3& back, int res, double angle_x);

// A square res x res camera at `centre` looking at the origin with +z as the up hint.
Camera look_at_origin(const Vec3& centre, int res);

// The ray through continuous pixel coordinates (px, py) (pixel (i, j)'s centre is
// (i + 0.5, j + 0.5)): direction R (x, -y, -1) with (x, y) = undistort((px - W/2)/f, (py - H/2)/f)
// (the identity for a pinhole), not normalised, so its t equals depth along the optical axis.
Ray camera_ray(const Camera& cam, double px, double py);

// Train views: a golden-angle spiral covering the elevation band uniformly by area, with a
// seed-dependent rotation and stratum offset (std::mt19937_64, portable conversion to [0,1)).
std::vector<Camera> train_cameras(int count, int res, uint64_t seed);

// Test views: an evenly spaced orbit at kTestElevationDeg (independent of the seed).
std::vector<Camera> test_cameras(int count, int res);

}  // namespace ablenerf::synth
