#include "data/scene_frame.h"

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>
#include <sstream>

#include "util/errors.h"
#include "util/vec3.h"
#include "data/data_config.h"

namespace ablenerf {

namespace {

using V3 = Vec3;

V3 column(const Pose34& p, int c) {
  return {p[static_cast<size_t>(c)], p[static_cast<size_t>(4 + c)], p[static_cast<size_t>(8 + c)]};
}

// The rotation taking unit vector `a` to +z (Rodrigues about a x z).
std::array<double, 9> rotation_to_z(const V3& a) {
  const V3 z{0, 0, 1};
  const V3 v = cross(a, z);
  const double c = dot(a, z), s = length(v);
  if (s < 1e-12) {
    if (c > 0) return {1, 0, 0, 0, 1, 0, 0, 0, 1};
    return {1, 0, 0, 0, -1, 0, 0, 0, -1};  // a = -z: half a turn about x
  }
  const V3 k{v[0] / s, v[1] / s, v[2] / s};
  const double K[3][3] = {{0, -k[2], k[1]}, {k[2], 0, -k[0]}, {-k[1], k[0], 0}};
  std::array<double, 9> r{};
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      double kk = 0;
      for (int m = 0; m < 3; ++m) kk += K[i][m] * K[m][j];
      r[static_cast<size_t>(i * 3 + j)] = (i == j ? 1.0 : 0.0) + s * K[i][j] + (1 - c) * kk;
    }
  return r;
}

V3 rotate(const std::array<double, 9>& r, const V3& v) {
  return {r[0] * v[0] + r[1] * v[1] + r[2] * v[2], r[3] * v[0] + r[4] * v[1] + r[5] * v[2],
          r[6] * v[0] + r[7] * v[1] + r[8] * v[2]};
}
V3 rotate_t(const std::array<double, 9>& r, const V3& v) {
  return {r[0] * v[0] + r[3] * v[1] + r[6] * v[2], r[1] * v[0] + r[4] * v[1] + r[7] * v[2],
          r[2] * v[0] + r[5] * v[1] + r[8] * v[2]};
}

// Solves the 3x3 system A x = b (Cramer); false when A is near singular relative to its size.
bool solve3(const double A[3][3], const V3& b, V3& x) {
  const double det = A[0][0] * (A[1][1] * A[2][2] - A[1][2] * A[2][1]) -
                     A[0][1] * (A[1][0] * A[2][2] - A[1][2] * A[2][0]) +
                     A[0][2] * (A[1][0] * A[2][1] - A[1][1] * A[2][0]);
  double scale = 0;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) scale = std::max(scale, std::abs(A[i][j]));
  if (!(std::abs(det) > 1e-6 * scale * scale * scale)) return false;
  for (int c = 0; c < 3; ++c) {
    double M[3][3];
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) M[i][j] = j == c ? b[static_cast<size_t>(i)] : A[i][j];
    x[static_cast<size_t>(c)] =
        (M[0][0] * (M[1][1] * M[2][2] - M[1][2] * M[2][1]) - M[0][1] * (M[1][0] * M[2][2] - M[1][2] * M[2][0]) +
         M[0][2] * (M[1][0] * M[2][1] - M[1][1] * M[2][0])) /
        det;
  }
  return true;
}

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  const size_t k = std::min(v.size() - 1, static_cast<size_t>(q * static_cast<double>(v.size() - 1)));
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
  return v[k];
}

// Points used for the bounds: at most this many (evenly strided), so a large COLMAP model costs
// milliseconds.
constexpr size_t kMaxBoundPoints = 20000;

// The sparse points the bounds use (capture units): every one, or kMaxBoundPoints evenly strided.
std::vector<V3> bound_points(const Capture& cap) {
  std::vector<V3> points;
  const size_t stride = std::max<size_t>(1, cap.points.size() / kMaxBoundPoints);
  for (size_t i = 0; i < cap.points.size(); i += stride) points.push_back(to_vec3(cap.points[i]));
  return points;
}

// Depths (capture units, along each optical axis) of the sparse points in front of each camera;
// InputError(root, "points") when none is.
std::vector<double> point_depths(const Capture& cap, const std::vector<Pose34>& poses, const std::string& root) {
  std::vector<double> depths;
  const std::vector<V3> points = bound_points(cap);
  for (const auto& p : poses) {
    const V3 o = column(p, 3), z = column(p, 2);
    for (const V3& q : points) {
      const double d = -dot(q - o, z);
      if (d > 0) depths.push_back(d);
    }
  }
  if (depths.empty()) throw InputError(root, "points", "no sparse point lies in front of any camera");
  return depths;
}

// The smallest near and largest far of the LLFF bounds (capture units); the capture has some.
std::array<double, 2> bounds_range(const Capture& cap) {
  std::array<double, 2> r = cap.bounds.front();
  for (const auto& b : cap.bounds) r[0] = std::min(r[0], b[0]), r[1] = std::max(r[1], b[1]);
  return r;
}

// The closest content in front of the cameras, capture units: the 1st percentile of the sparse
// points' depths, else the smallest LLFF near bound.
double nearest_content(const Capture& cap, const std::vector<Pose34>& poses, const std::string& root) {
  if (cap.points.empty()) return bounds_range(cap)[0];
  return percentile(point_depths(cap, poses, root), 0.01);
}

SceneFrame fit_forward_facing(const Capture& cap, const std::vector<Pose34>& poses, const V3& mean, const V3& back,
                              const V3& up_sum, const std::string& root) {
  SceneFrame f;
  f.kind = SceneKind::ForwardFacing;
  f.faces_one_way = true;
  f.centre = to_array(mean);
  // Rows of R: right = up x back, up' = back x right, back (so R back = +z, the cameras look down -z).
  V3 right = cross(up_sum, back);
  const double rn = length(right);
  if (!(rn > 1e-9)) throw InputError(root, "poses", "the cameras' up vectors are parallel to their viewing direction");
  right = {right[0] / rn, right[1] / rn, right[2] / rn};
  const V3 up = cross(back, right);
  f.rotation = {right[0], right[1], right[2], up[0], up[1], up[2], back[0], back[1], back[2]};
  const double closest = nearest_content(cap, poses, root);
  if (!(closest > 0)) throw InputError(root, "bounds", "the scene's near bound must be positive");
  f.scale = 1.0 / (kForwardNearFraction * closest);
  f.near = 0;
  f.far = 1;
  f.bounds_source = cap.points.empty() ? "llff bounds" : "points";
  const Intrinsics& k = cap.splits.front().frames.front().camera;
  f.ndc_a = 2 * k.fx / k.width;
  f.ndc_b = 2 * k.fy / k.height;
  return f;
}

}  // namespace

bool SceneFrame::identity() const {
  return scale == 1 && centre == std::array<double, 3>{0, 0, 0} &&
         rotation == std::array<double, 9>{1, 0, 0, 0, 1, 0, 0, 0, 1};
}

std::array<double, 3> SceneFrame::point_to_scene(const std::array<double, 3>& p) const {
  const V3 r = rotate(rotation, to_vec3(p) - to_vec3(centre));
  return {scale * r[0], scale * r[1], scale * r[2]};
}

Pose34 SceneFrame::to_scene(const Pose34& c2w) const {
  Pose34 out{};
  for (int c = 0; c < 3; ++c) {
    const V3 col = rotate(rotation, column(c2w, c));
    for (int r = 0; r < 3; ++r) out[static_cast<size_t>(r * 4 + c)] = static_cast<float>(col[static_cast<size_t>(r)]);
  }
  const V3 t = to_vec3(point_to_scene(to_array(column(c2w, 3))));
  for (int r = 0; r < 3; ++r) out[static_cast<size_t>(r * 4 + 3)] = static_cast<float>(t[static_cast<size_t>(r)]);
  return out;
}

Pose34 SceneFrame::to_capture(const Pose34& c2w) const {
  Pose34 out{};
  for (int c = 0; c < 3; ++c) {
    const V3 col = rotate_t(rotation, column(c2w, c));
    for (int r = 0; r < 3; ++r) out[static_cast<size_t>(r * 4 + c)] = static_cast<float>(col[static_cast<size_t>(r)]);
  }
  const V3 t = column(c2w, 3);
  const V3 back = rotate_t(rotation, {t[0] / scale, t[1] / scale, t[2] / scale});
  for (int r = 0; r < 3; ++r)
    out[static_cast<size_t>(r * 4 + 3)] =
        static_cast<float>(back[static_cast<size_t>(r)] + centre[static_cast<size_t>(r)]);
  return out;
}

std::string SceneFrame::to_json() const {
  nlohmann::json j;
  j["rotation"] = rotation;
  j["centre"] = centre;
  j["scale"] = scale;
  j["scene"] = name_of(kind);
  j["near"] = near;
  j["far"] = far;
  j["bounds_source"] = bounds_source;
  j["faces_one_way"] = faces_one_way;
  j["looks_outward"] = looks_outward;
  if (!centre_source.empty()) j["centre_source"] = centre_source;
  if (!radius_source.empty()) j["radius_source"] = radius_source;
  if (kind == SceneKind::ForwardFacing) {
    j["ndc_a"] = ndc_a;
    j["ndc_b"] = ndc_b;
  }
  j["convention"] = "x_scene = scale * rotation (x_capture - centre); rotation row-major";
  return j.dump(2) + "\n";
}

SceneFrame SceneFrame::from_json(const std::string& text, const std::string& origin) {
  SceneFrame f;
  try {
    const auto j = nlohmann::json::parse(text);
    f.rotation = j.at("rotation").get<std::array<double, 9>>();
    f.centre = j.at("centre").get<std::array<double, 3>>();
    f.scale = j.at("scale").get<double>();
    const auto kind = enum_from_name<SceneKind>(j.at("scene").get<std::string>());
    if (!kind || *kind == SceneKind::Auto)
      throw InputError(origin, "scene", "must be \"bounded\", \"unbounded\" or \"forward\"");
    f.kind = *kind;
    f.ndc_a = j.value("ndc_a", 0.0);
    f.ndc_b = j.value("ndc_b", 0.0);
    f.near = j.at("near").get<double>();
    f.far = j.at("far").get<double>();
    f.bounds_source = j.value("bounds_source", "");
    f.faces_one_way = j.value("faces_one_way", f.kind == SceneKind::ForwardFacing);  // absent before it was kept
    f.looks_outward = j.value("looks_outward", false);
    f.centre_source = j.value("centre_source", "");
    f.radius_source = j.value("radius_source", "");
  } catch (const nlohmann::json::exception& e) {
    throw InputError(origin, "", std::string("not a scene frame: ") + e.what());
  }
  if (!(f.scale > 0 && std::isfinite(f.scale))) throw InputError(origin, "scale", "must be positive");
  if (!(f.near >= 0 && f.far > f.near)) throw InputError(origin, "far", "need 0 <= near < far");
  if (f.kind == SceneKind::ForwardFacing &&
      !(f.ndc_a > 0 && f.ndc_b > 0 && std::isfinite(f.ndc_a) && std::isfinite(f.ndc_b)))
    throw InputError(origin, "ndc_a", "a forward-facing scene needs positive ndc_a and ndc_b");
  return f;
}

std::string SceneFrame::describe() const {
  std::ostringstream o;
  o << name_of(kind) << " scene, near " << near << " far " << far << " (" << bounds_source << ")";
  if (kind == SceneKind::ForwardFacing) o << ", NDC rays (ndc_a " << ndc_a << ", ndc_b " << ndc_b << ")";
  if (kind != SceneKind::ForwardFacing && faces_one_way) o << ", cameras facing one way";
  if (looks_outward) o << ", cameras looking outward (a room from inside)";
  if (!identity())
    o << "; capture -> scene: centre (" << centre[0] << ", " << centre[1] << ", " << centre[2] << ")"
      << (centre_source.empty() ? "" : " [" + centre_source + "]") << ", scale " << scale
      << (radius_source.empty() ? "" : " [radius " + std::to_string(1.0 / scale) + ": " + radius_source + "]")
      << ", up (" << rotation[6] << ", " << rotation[7] << ", " << rotation[8] << ") -> +z";
  return o.str();
}

SceneFrame fit_scene_frame(const Capture& cap, const std::string& root, SceneKind requested, double near, double far,
                           bool bounds_from_config, bool auto_ndc, const SceneFrameOverrides& over) {
  SceneFrame f;
  const char* over_key = over.centre != SceneCentre::Auto ? "data.scene_centre" : "data.scene_radius";
  if (over.any() && cap.synthetic)
    throw InputError(root, over_key, "a Blender scene keeps its own frame: leave it unset");
  if (over.any() && requested == SceneKind::ForwardFacing)
    throw InputError(root, over_key, "applies to bounded and unbounded scenes, not data.scene = \"forward\"");
  if (!(over.radius >= 0 && std::isfinite(over.radius)))
    throw InputError(root, "data.scene_radius", "must be > 0 (the capture's units), or 0 to choose from the cameras");
  if (cap.synthetic) {
    f.kind = requested == SceneKind::Unbounded ? SceneKind::Unbounded : SceneKind::Bounded;
    f.near = near;
    f.far = f.kind == SceneKind::Unbounded ? kUnboundedFar : far;
    return f;
  }
  std::vector<Pose34> poses;
  for (const auto& s : cap.splits)
    for (const auto& fr : s.frames) poses.push_back(fr.pose);
  if (poses.empty()) throw InputError(root, "frames", "no frames");
  // Centre: the nearest point to every optical axis (-z of each camera), when the cameras look at
  // a common region in front of them; else the mean camera position.
  V3 mean{0, 0, 0}, up{0, 0, 0};
  double A[3][3] = {{0}};
  V3 b{0, 0, 0};
  V3 back{0, 0, 0};  // the sum of the cameras' backward axes
  for (const auto& p : poses) {
    const V3 o = column(p, 3), y = column(p, 1), z = column(p, 2);
    const V3 d{-z[0], -z[1], -z[2]};
    for (int i = 0; i < 3; ++i) {
      mean[static_cast<size_t>(i)] += o[static_cast<size_t>(i)] / static_cast<double>(poses.size());
      up[static_cast<size_t>(i)] += y[static_cast<size_t>(i)];
      back[static_cast<size_t>(i)] += z[static_cast<size_t>(i)];
    }
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) {
        const double m = (i == j ? 1.0 : 0.0) - d[static_cast<size_t>(i)] * d[static_cast<size_t>(j)];
        A[i][j] += m;
        b[static_cast<size_t>(i)] += m * o[static_cast<size_t>(j)];
      }
  }
  double spread = 0;
  for (const auto& p : poses) spread = std::max(spread, length(column(p, 3) - mean));
  if (!(spread > 1e-9 * (1 + length(mean))))
    throw InputError(root, "poses", "every camera is at the same point (degenerate poses: nothing to triangulate)");
  // Forward-facing: every optical axis close to the mean one, and a known near bound.
  const double back_norm = length(back);
  bool facing_one_way = back_norm > 1e-9;
  if (facing_one_way) {
    for (size_t i = 0; i < 3; ++i) back[i] /= back_norm;
    for (const auto& p : poses)
      facing_one_way = facing_one_way && dot(column(p, 2), back) >= std::cos(kForwardFacingMaxAngleDeg * M_PI / 180);
  }
  const bool has_near = !cap.points.empty() || !cap.bounds.empty();
  if (requested == SceneKind::ForwardFacing && !has_near)
    throw InputError(root, "data.scene", "forward needs the scene's near bound: sparse points (COLMAP) or LLFF bounds");
  if (requested == SceneKind::ForwardFacing && !facing_one_way)
    throw InputError(root, "data.scene",
                     "forward needs cameras that all look the same way (none may turn more than " +
                         std::to_string(static_cast<int>(kForwardFacingMaxAngleDeg)) +
                         " degrees from their mean direction); use unbounded");
  if (requested == SceneKind::ForwardFacing ||
      (requested == SceneKind::Auto && auto_ndc && !over.any() && facing_one_way && has_near))
    return fit_forward_facing(cap, poses, mean, back, up, root);

  V3 focus;
  int in_front = 0;
  const bool solved = solve3(A, b, focus);
  if (solved) {
    for (const auto& p : poses) {
      const V3 z = column(p, 2);
      in_front += dot(focus - column(p, 3), V3{-z[0], -z[1], -z[2]}) > 0;
    }
  }
  const bool use_focus = 2 * in_front > static_cast<int>(poses.size()) && length(focus - mean) < 10 * spread;
  if (over.centre == SceneCentre::Focus && !solved)
    throw InputError(root, "data.scene_centre",
                     "\"focus\": the cameras' optical axes are parallel and meet nowhere; use \"cameras\"");
  const bool centre_focus = over.centre == SceneCentre::Auto ? use_focus : over.centre == SceneCentre::Focus;
  f.centre = to_array(centre_focus ? focus : mean);
  f.centre_source = std::string(centre_focus ? "focus" : "cameras") +
                    (over.centre == SceneCentre::Auto ? "" : " (data.scene_centre)");
  const double up_norm = length(up);
  f.rotation = up_norm > 1e-9 ? rotation_to_z({up[0] / up_norm, up[1] / up_norm, up[2] / up_norm})
                              : std::array<double, 9>{1, 0, 0, 0, 1, 0, 0, 0, 1};
  double radius = 0;
  for (const auto& p : poses) radius = std::max(radius, length(column(p, 3) - to_vec3(f.centre)));
  // Cameras that look at no common region in front of them and not all one way look out at what
  // surrounds them (a room from inside): the scene lies beyond the cameras, and a unit sphere
  // through the farthest camera would leave it all to the contraction's thin outer shell. With
  // sparse points the sphere holds half of them instead (their median distance from the centre).
  f.looks_outward = !use_focus && !facing_one_way;
  f.radius_source = "farthest camera";
  if (f.looks_outward && !cap.points.empty()) {
    std::vector<double> distances;
    for (const V3& q : bound_points(cap)) distances.push_back(length(q - to_vec3(f.centre)));
    const double median = percentile(distances, 0.5);
    if (median > radius) radius = median, f.radius_source = "median sparse point";
  }
  if (over.radius > 0) radius = over.radius, f.radius_source = "data.scene_radius";
  f.scale = 1.0 / radius;
  f.kind = requested == SceneKind::Bounded ? SceneKind::Bounded : SceneKind::Unbounded;
  f.faces_one_way = facing_one_way;

  // Bounds, in scene units.
  if (bounds_from_config) {
    f.near = near, f.far = far, f.bounds_source = "config";
  } else if (!cap.points.empty()) {
    const std::vector<double> depths = point_depths(cap, poses, root);
    f.near = 0.5 * f.scale * percentile(depths, 0.01);
    f.far = 1.5 * f.scale * percentile(depths, 0.99);
    f.bounds_source = "points";
  } else if (!cap.bounds.empty()) {
    const auto [lo, hi] = bounds_range(cap);
    f.near = 0.9 * lo * f.scale;
    f.far = 1.1 * hi * f.scale;
    f.bounds_source = "llff bounds";
  } else {
    // Only cameras: the scene is assumed to lie around the centre, within the cameras' sphere.
    f.near = 0.05;
    f.far = 4.0;
    f.bounds_source = "cameras";
  }
  f.near = std::max(f.near, 1e-3);
  if (f.kind == SceneKind::Unbounded) f.far = kUnboundedFar;
  if (!(f.far > f.near)) f.far = f.near * 100;
  return f;
}

}  // namespace ablenerf
