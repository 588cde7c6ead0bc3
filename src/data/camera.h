#pragma once
// One image's camera (the small interface the ray generator calls): pinhole intrinsics in pixels
// plus a lens model that maps undistorted normalised image coordinates to the distorted ones the
// sensor recorded. The lens models live one per file (lens_radial_tangential.cpp,
// lens_fisheye.cpp; the pinhole is the identity) behind lens.h. Coordinates follow OpenCV and
// COLMAP: normalised x = (u - cx) / fx, y = (v - cy) / fy with v growing downwards; the ray
// generator flips y and z to the project's OpenGL camera axes afterwards. Torch-free (the capture
// readers that fill it are fuzzed without LibTorch); the tensor form is CameraTable (rays.h).
#include <array>
#include <string>
#include <vector>

namespace ablenerf {

// The lens models every capture format maps onto (COLMAP's SIMPLE_PINHOLE/PINHOLE are Pinhole,
// SIMPLE_RADIAL/RADIAL/OPENCV are RadialTangential with the missing coefficients 0, OPENCV_FISHEYE
// is Fisheye).
enum class LensModel : int64_t {
  Pinhole = 0,
  // OpenCV's (Brown-Conrady) model: r^2 = x^2 + y^2, radial = 1 + k1 r^2 + k2 r^4 + k3 r^6,
  // xd = x radial + 2 p1 x y + p2 (r^2 + 2 x^2), yd = y radial + p1 (r^2 + 2 y^2) + 2 p2 x y.
  RadialTangential = 1,
  // OpenCV's fisheye (equidistant with a polynomial): theta = atan(r),
  // theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8), (xd, yd) = theta_d / r (x, y).
  Fisheye = 2,
};
const char* lens_model_name(LensModel m);

// Index of each coefficient in Intrinsics::dist and in CameraTable's parameter rows.
enum LensCoeff { kK1 = 0, kK2, kK3, kK4, kP1, kP2, kLensCoeffs };

// One image's camera at the resolution it is used at. (The historical name: every image of a
// Blender scene shares one pinhole, which was all a camera could be.)
struct Intrinsics {
  double fx = 1, fy = 1, cx = 0, cy = 0;
  int width = 0, height = 0;
  LensModel model = LensModel::Pinhole;
  std::array<double, kLensCoeffs> dist{};  // k1 k2 k3 k4 p1 p2 (unused ones 0)

  bool distorted() const;
  // The same camera for the image resized by `s` (pixel sizes scale, the lens does not).
  Intrinsics scaled(double s, int new_width, int new_height) const;
  // "PINHOLE 800x800 f=(1111.1, 1111.1) c=(400, 400)" and the non-zero coefficients.
  std::string describe() const;
};

}  // namespace ablenerf
