#include "data/camera.h"

#include <sstream>

namespace ablenerf {

const char* lens_model_name(LensModel m) {
  switch (m) {
    case LensModel::Pinhole: return "PINHOLE";
    case LensModel::RadialTangential: return "OPENCV";
    case LensModel::Fisheye: return "OPENCV_FISHEYE";
  }
  return "?";
}

bool Intrinsics::distorted() const {
  if (model == LensModel::Fisheye) return true;  // even with k = 0 it is not a pinhole
  for (double c : dist)
    if (c != 0.0) return true;
  return false;
}

Intrinsics Intrinsics::scaled(double s, int new_width, int new_height) const {
  Intrinsics k = *this;
  k.fx *= s;
  k.fy *= s;
  k.cx *= s;
  k.cy *= s;
  k.width = new_width;
  k.height = new_height;
  return k;
}

std::string Intrinsics::describe() const {
  std::ostringstream o;
  o << lens_model_name(model) << " " << width << "x" << height << " f=(" << fx << ", " << fy << ") c=(" << cx << ", "
    << cy << ")";
  static const char* const names[kLensCoeffs] = {"k1", "k2", "k3", "k4", "p1", "p2"};
  for (int i = 0; i < kLensCoeffs; ++i)
    if (dist[static_cast<size_t>(i)] != 0.0) o << " " << names[i] << "=" << dist[static_cast<size_t>(i)];
  return o.str();
}

}  // namespace ablenerf
