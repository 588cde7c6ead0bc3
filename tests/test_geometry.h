#pragma once
// Small double-precision vector helpers and a look-at camera for the tests that build captures by
// hand (the loaders' conventions are checked against these, so they share nothing with src/).
#include <array>
#include <cmath>

namespace ablenerf::test {

using V3 = std::array<double, 3>;
inline V3 sub3(const V3& a, const V3& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
inline double dot3(const V3& a, const V3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
inline V3 cross3(const V3& a, const V3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
inline V3 unit3(const V3& a) {
  const double n = std::sqrt(dot3(a, a));
  return {a[0] / n, a[1] / n, a[2] / n};
}

// A camera at `eye` looking at `target` with world up `up`: its right, up and backward axes
// (OpenGL: it looks along -back).
struct Frame3 {
  V3 right, up, back, eye;
};
inline Frame3 look_at(const V3& eye, const V3& target, const V3& up) {
  Frame3 f;
  f.back = unit3(sub3(eye, target));
  f.right = unit3(cross3(up, f.back));
  f.up = cross3(f.back, f.right);
  f.eye = eye;
  return f;
}

}  // namespace ablenerf::test
