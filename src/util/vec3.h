#pragma once
// The project's one double-precision 3-vector, for code that works on single points and directions
// rather than tensors: the demo scene's ray tracer (src/synth, per ray on the CPU, where a small
// value type beats tensor calls by orders of magnitude) and the scene frame's fit
// (data/scene_frame.cpp). Points stored as std::array<double, 3> convert with to_vec3 / to_array.
#include <array>
#include <cmath>
#include <cstddef>

namespace ablenerf {

struct Vec3 {
  double x = 0, y = 0, z = 0;
  constexpr Vec3() = default;
  constexpr Vec3(double x_, double y_, double z_) : x(x_), y(y_), z(z_) {}

  constexpr Vec3 operator+(const Vec3& o) const { return {x + o.x, y + o.y, z + o.z}; }
  constexpr Vec3 operator-(const Vec3& o) const { return {x - o.x, y - o.y, z - o.z}; }
  constexpr Vec3 operator-() const { return {-x, -y, -z}; }
  constexpr Vec3 operator*(double s) const { return {x * s, y * s, z * s}; }
  constexpr Vec3 operator/(double s) const { return {x / s, y / s, z / s}; }
  // Component-wise product: colour filtering (albedo * irradiance, tint * radiance).
  constexpr Vec3 operator*(const Vec3& o) const { return {x * o.x, y * o.y, z * o.z}; }
  Vec3& operator+=(const Vec3& o) {
    x += o.x;
    y += o.y;
    z += o.z;
    return *this;
  }
  double operator[](size_t i) const { return i == 0 ? x : i == 1 ? y : z; }
  double& operator[](size_t i) { return i == 0 ? x : i == 1 ? y : z; }
  bool operator==(const Vec3& o) const { return x == o.x && y == o.y && z == o.z; }
};

inline Vec3 to_vec3(const std::array<double, 3>& a) { return {a[0], a[1], a[2]}; }
inline std::array<double, 3> to_array(const Vec3& v) { return {v.x, v.y, v.z}; }

constexpr Vec3 operator*(double s, const Vec3& v) { return v * s; }
constexpr double dot(const Vec3& a, const Vec3& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
constexpr Vec3 cross(const Vec3& a, const Vec3& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline double length(const Vec3& v) { return std::sqrt(dot(v, v)); }
inline Vec3 normalize(const Vec3& v) { return v / length(v); }
// Linear interpolation a + (b - a) s.
constexpr Vec3 mix(const Vec3& a, const Vec3& b, double s) { return a + (b - a) * s; }
// Mirror direction of d about the unit normal n.
constexpr Vec3 reflect(const Vec3& d, const Vec3& n) { return d - n * (2.0 * dot(d, n)); }

}  // namespace ablenerf
