#include "synth/room.h"

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace ablenerf::synth {

namespace {

// Shadow rays start this far off the surface so they do not re-hit it through round-off.
constexpr double kShadowOffset = 1e-7;

constexpr Vec3 kAmbient{0.20, 0.20, 0.22};

enum Face { kFloor = 0, kCeiling, kWallWest, kWallEast, kWallSouth, kWallNorth };

// ---- Texture building blocks (all deterministic functions of the surface point) ----

// A hash of three integers to [0, 1) (SplitMix64's finaliser): per-plank and per-board tones.
double hash01(int64_t a, int64_t b, int64_t c) {
  uint64_t z = static_cast<uint64_t>(a) * 0x9e3779b97f4a7c15ULL ^ static_cast<uint64_t>(b) * 0xbf58476d1ce4e5b9ULL ^
               static_cast<uint64_t>(c) * 0x94d049bb133111ebULL;
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  z ^= z >> 31;
  return static_cast<double>(z >> 11) * 0x1.0p-53;
}

int64_t cell(double x, double size) { return static_cast<int64_t>(std::floor(x / size)); }
bool checker(double u, double v, double size) { return ((cell(u, size) + cell(v, size)) & 1) != 0; }
// Whether x lies within half_width of a multiple of spacing (grid lines, plank gaps).
bool near_line(double x, double spacing, double half_width) {
  const double f = x / spacing - std::floor(x / spacing);
  return f * spacing < half_width || (1.0 - f) * spacing < half_width;
}

// The 2D coordinates of a room face: floor and ceiling (x, y); the walls (along the wall, z).
void face_uv(int face, const Vec3& p, double& u, double& v) {
  switch (face) {
    case kFloor:
    case kCeiling: u = p.x, v = p.y; return;
    case kWallWest:
    case kWallEast: u = p.y, v = p.z; return;
    default: u = p.x, v = p.z; return;
  }
}

// Floor: planks 0.25 wide running along x, boards of 1.2 staggered per plank, each board with its
// own tone, a wavy grain and dark gaps between planks and boards.
Vec3 floor_albedo(double x, double y) {
  constexpr double kPlank = 0.25, kBoard = 1.2;
  const int64_t plank = cell(y, kPlank);
  const double xs = x + kBoard * hash01(plank, 17, 3);  // stagger the board joints
  const int64_t board = cell(xs, kBoard);
  const double tone = 0.75 + 0.45 * hash01(plank, board, 5);
  const double grain = 0.88 + 0.12 * std::sin(2.0 * M_PI * (7.0 * x + 0.8 * std::sin(9.0 * y + 3.0 * plank)));
  Vec3 c = Vec3{0.55, 0.36, 0.20} * (tone * grain);
  if (near_line(y, kPlank, 0.008) || near_line(xs, kBoard, 0.006)) c = c * 0.45;
  return c;
}

// Ceiling: plain light grey with a faint 0.5 grid.
Vec3 ceiling_albedo(double x, double y) {
  const bool line = near_line(x, 0.5, 0.012) || near_line(y, 0.5, 0.012);
  return line ? Vec3{0.70, 0.70, 0.70} : Vec3{0.82, 0.82, 0.80};
}

// A picture on a wall: a rectangle in the wall's (u, v), with a dark frame and a pattern of its own.
struct Picture {
  int face;
  double u0, u1, v0, v1;
  Vec3 colour;
};

const Picture kPictures[] = {
    {kWallWest, -1.2, -0.3, 1.1, 1.8, {0.85, 0.45, 0.10}},  {kWallWest, 0.5, 1.4, 0.9, 1.5, {0.15, 0.55, 0.50}},
    {kWallEast, -0.8, 0.4, 1.2, 1.9, {0.60, 0.15, 0.55}},   {kWallEast, 0.9, 1.5, 0.7, 1.6, {0.85, 0.80, 0.15}},
    {kWallSouth, -1.9, -0.9, 1.0, 1.7, {0.15, 0.25, 0.70}}, {kWallSouth, 0.2, 0.8, 1.3, 2.1, {0.80, 0.20, 0.20}},
    {kWallNorth, 0.6, 1.8, 1.2, 2.0, {0.20, 0.60, 0.15}},   {kWallNorth, -2.1, -1.5, 1.4, 2.0, {0.70, 0.35, 0.75}},
};
constexpr double kFrameWidth = 0.05;

// The pictures' inside: concentric rings around the picture's centre, 0.08 apart, over the colour.
bool picture_albedo(int face, double u, double v, Vec3& out) {
  for (const Picture& pic : kPictures) {
    if (pic.face != face || u < pic.u0 || u > pic.u1 || v < pic.v0 || v > pic.v1) continue;
    if (u < pic.u0 + kFrameWidth || u > pic.u1 - kFrameWidth || v < pic.v0 + kFrameWidth || v > pic.v1 - kFrameWidth) {
      out = {0.08, 0.07, 0.06};
      return true;
    }
    const double r = std::hypot(u - 0.5 * (pic.u0 + pic.u1), v - 0.5 * (pic.v0 + pic.v1));
    out = (cell(r, 0.08) & 1) ? pic.colour : mix(pic.colour, Vec3{0.9, 0.9, 0.9}, 0.6);
    return true;
  }
  return false;
}

// The walls: each its own colour and pattern (cell sizes 0.2-0.5), a dark skirting board below
// 0.1, and the pictures.
Vec3 wall_albedo(int face, double u, double v) {
  Vec3 pic;
  if (picture_albedo(face, u, v, pic)) return pic;
  if (v < 0.1) return {0.12, 0.10, 0.09};
  switch (face) {
    case kWallWest: return checker(u, v, 0.2) ? Vec3{0.50, 0.58, 0.75} : Vec3{0.38, 0.45, 0.62};   // blue-grey
    case kWallEast: return (cell(u, 0.3) & 1) ? Vec3{0.80, 0.68, 0.42} : Vec3{0.66, 0.54, 0.30};   // ochre stripes
    case kWallSouth: return checker(u, v, 0.4) ? Vec3{0.52, 0.72, 0.52} : Vec3{0.36, 0.56, 0.38};  // green
    default: return (cell(u + v, 0.35) & 1) ? Vec3{0.82, 0.58, 0.58} : Vec3{0.68, 0.42, 0.45};     // pink diagonals
  }
}

// The furniture's checkers (in the two coordinates of the face hit, so that a face lying on a cell
// boundary does not flicker) and the ball's longitude/latitude checker.
struct BoxLook {
  Vec3 a, b;
  double cell;
};
const BoxLook kBoxLooks[] = {
    {{0.80, 0.20, 0.12}, {0.90, 0.62, 0.25}, 0.12},  // table: red and orange
    {{0.12, 0.25, 0.75}, {0.55, 0.70, 0.90}, 0.16},  // cabinet: blue
    {{0.15, 0.60, 0.20}, {0.70, 0.85, 0.30}, 0.10},  // bench: green
};
constexpr Vec3 kBallA{0.85, 0.75, 0.10}, kBallB{0.45, 0.10, 0.60};
constexpr int kBallLon = 12, kBallLat = 6;

// The axis (0, 1, 2) a box face point lies on: the coordinate closest to the box's lo or hi.
int box_face_axis(const Box& b, const Vec3& p) {
  int axis = 0;
  double best = std::numeric_limits<double>::infinity();
  for (size_t a = 0; a < 3; ++a) {
    const double d = std::min(std::abs(p[a] - b.lo[a]), std::abs(p[a] - b.hi[a]));
    if (d < best) best = d, axis = static_cast<int>(a);
  }
  return axis;
}

Vec3 clamp_albedo(const Vec3& c) {
  return {std::clamp(c.x, kRoomAlbedoMin, kRoomAlbedoMax), std::clamp(c.y, kRoomAlbedoMin, kRoomAlbedoMax),
          std::clamp(c.z, kRoomAlbedoMin, kRoomAlbedoMax)};
}

// Whether the segment from p to the light crosses the furniture or the ball.
bool shadowed(const Vec3& p, const Vec3& light) {
  const Ray r{p, light - p};  // t in (0, 1) lies between p and the light
  for (const Box& b : room_furniture())
    if (intersect_box(b, r, 0.0) < 1.0) return true;
  return intersect_sphere(room_ball(), r, 0.0) < 1.0;
}

}  // namespace

const std::vector<Box>& room_furniture() {
  // Clear of the walls by 0.05 (no face shares a wall's plane) and of the cameras' region (a disc
  // of radius 0.6 around the z axis at heights 1.2-1.7, room_camera.h).
  static const std::vector<Box> boxes = {
      {"table", {-1.40, 1.00, 0.00}, {-0.20, 1.70, 0.75}},    // 1.2 x 0.7 x 0.75, by the north wall
      {"cabinet", {1.95, -1.95, 0.00}, {2.45, -1.45, 1.60}},  // 0.5 x 0.5 x 1.6, in the south-east corner
      {"bench", {-2.45, -1.30, 0.00}, {-2.00, -0.30, 0.45}},  // 0.45 x 1.0 x 0.45, by the west wall
  };
  return boxes;
}

const Sphere& room_ball() {
  static const Sphere ball{"ball", MaterialKind::Diffuse, {1.15, 0.95, 0.35}, 0.35};
  return ball;
}

int room_object_count() { return kRoomFaces + static_cast<int>(room_furniture().size()) + 1; }

const char* room_object_name(int object) {
  if (object < 0 || object >= room_object_count()) return "?";
  if (object < kRoomFaces) return kRoomFaceNames[object];
  const size_t box = static_cast<size_t>(object - kRoomFaces);
  return box < room_furniture().size() ? room_furniture()[box].name : room_ball().name;
}

const std::vector<PointLight>& room_lights() {
  static const std::vector<PointLight> lights = {
      {"ceiling_lamp", {0.40, -0.30, 2.35}, {2.6, 2.4, 2.1}},  // warm white, over the middle
      {"window_light", {-1.50, 0.90, 1.90}, {0.9, 1.0, 1.3}},  // cool, towards the north-west corner
      {"floor_lamp", {1.60, 1.20, 1.50}, {1.1, 0.8, 0.5}},     // orange, towards the north-east corner
  };
  return lights;
}

Vec3 room_ambient() { return kAmbient; }

double intersect_box(const Box& b, const Ray& r, double t_min) {
  // Slabs: the ray is inside the box for t in [max of the entries, min of the exits].
  double t_in = -std::numeric_limits<double>::infinity(), t_out = std::numeric_limits<double>::infinity();
  for (size_t a = 0; a < 3; ++a) {
    if (r.dir[a] == 0.0) {
      if (r.origin[a] < b.lo[a] || r.origin[a] > b.hi[a]) return std::numeric_limits<double>::infinity();
      continue;
    }
    double t0 = (b.lo[a] - r.origin[a]) / r.dir[a], t1 = (b.hi[a] - r.origin[a]) / r.dir[a];
    if (t0 > t1) std::swap(t0, t1);
    t_in = std::max(t_in, t0);
    t_out = std::min(t_out, t1);
  }
  if (t_in > t_out) return std::numeric_limits<double>::infinity();
  if (t_in > t_min) return t_in;
  return t_out > t_min ? t_out : std::numeric_limits<double>::infinity();
}

Hit intersect_room(const Ray& r, double t_min) {
  Hit best;
  // The room's faces, seen from inside: the planes ahead of the ray on each axis; the nearest one
  // is where the ray leaves the box. (A ray from outside gets the same treatment and may "hit" a
  // plane beyond the box; the renderer only casts rays from inside.)
  for (size_t a = 0; a < 3; ++a) {
    if (r.dir[a] == 0.0) continue;
    const bool up = r.dir[a] > 0.0;
    const double t = ((up ? kRoomMax[a] : kRoomMin[a]) - r.origin[a]) / r.dir[a];
    if (t > t_min && t < best.t) {
      best.t = t;
      // Faces: floor (z lo), ceiling (z hi), west (x lo), east (x hi), south (y lo), north (y hi).
      best.object = a == 2   ? (up ? kCeiling : kFloor)
                    : a == 0 ? (up ? kWallEast : kWallWest)
                             : (up ? kWallNorth : kWallSouth);
    }
  }
  const auto& boxes = room_furniture();
  for (size_t i = 0; i < boxes.size(); ++i) {
    const double t = intersect_box(boxes[i], r, t_min);
    if (t < best.t) best.t = t, best.object = kRoomFaces + static_cast<int>(i);
  }
  const double t = intersect_sphere(room_ball(), r, t_min);
  if (t < best.t) best.t = t, best.object = kRoomFaces + static_cast<int>(boxes.size());
  return best;
}

Vec3 room_normal(int object, const Vec3& p) {
  switch (object) {
    case kFloor: return {0, 0, 1};
    case kCeiling: return {0, 0, -1};
    case kWallWest: return {1, 0, 0};
    case kWallEast: return {-1, 0, 0};
    case kWallSouth: return {0, 1, 0};
    case kWallNorth: return {0, -1, 0};
    default: break;
  }
  const size_t box = static_cast<size_t>(object - kRoomFaces);
  if (box >= room_furniture().size()) return (p - room_ball().centre) / room_ball().radius;
  const Box& b = room_furniture()[box];
  const int axis = box_face_axis(b, p);
  Vec3 n;
  const size_t a = static_cast<size_t>(axis);
  n[a] = std::abs(p[a] - b.lo[a]) < std::abs(p[a] - b.hi[a]) ? -1.0 : 1.0;
  return n;
}

Vec3 room_albedo(int object, const Vec3& p) {
  if (object < kRoomFaces) {
    double u, v;
    face_uv(object, p, u, v);
    if (object == kFloor) return clamp_albedo(floor_albedo(u, v));
    if (object == kCeiling) return clamp_albedo(ceiling_albedo(u, v));
    return clamp_albedo(wall_albedo(object, u, v));
  }
  const size_t box = static_cast<size_t>(object - kRoomFaces);
  if (box >= room_furniture().size()) {
    const Vec3 n = (p - room_ball().centre) / room_ball().radius;
    const double lon = (std::atan2(n.y, n.x) + M_PI) / (2.0 * M_PI);
    const double colat = std::acos(std::clamp(n.z, -1.0, 1.0)) / M_PI;
    const int iu = std::min(kBallLon - 1, static_cast<int>(lon * kBallLon));
    const int iv = std::min(kBallLat - 1, static_cast<int>(colat * kBallLat));
    return clamp_albedo(((iu + iv) & 1) ? kBallA : kBallB);
  }
  const Box& b = room_furniture()[box];
  const BoxLook& look = kBoxLooks[box % (sizeof(kBoxLooks) / sizeof(kBoxLooks[0]))];
  const size_t axis = static_cast<size_t>(box_face_axis(b, p));
  const double u = p[(axis + 1) % 3], v = p[(axis + 2) % 3];
  return clamp_albedo(checker(u, v, look.cell) ? look.a : look.b);
}

Vec3 trace_room(const Ray& r, int /*depth*/) {
  const Hit h = intersect_room(r, 0.0);
  if (!h.hit()) return {};
  const Vec3 p = r.at(h.t);
  const Vec3 n = room_normal(h.object, p);
  Vec3 irradiance = room_ambient();
  for (const PointLight& light : room_lights()) {
    const Vec3 to_light = light.position - p;
    const double d2 = dot(to_light, to_light);
    const double cos_l = dot(n, to_light) / std::sqrt(d2);
    if (cos_l <= 0.0 || shadowed(p + n * kShadowOffset, light.position)) continue;
    irradiance += light.intensity * (cos_l / std::max(d2, kRoomLightMinDistance * kRoomLightMinDistance));
  }
  return room_albedo(h.object, p) * irradiance;
}

SceneTracer room_tracer() { return {&intersect_room, &trace_room}; }

}  // namespace ablenerf::synth
