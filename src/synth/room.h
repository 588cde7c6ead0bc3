#pragma once
// The room scene's content (`ablenerf synth --scene room`): a closed box room, furnished with
// boxes and a ball, photographed from inside (room_camera.h): what real captures of rooms look
// like, cameras inside looking outward at surfaces all around them. Every surface is Lambertian
// with a procedural albedo that has detail at several scales (wood planks on the floor, a
// differently coloured and patterned wall on each side with a few pictures on it, a faint grid on
// the ceiling, checkered furniture), lit by an ambient term and a few point lights with
// inverse-square falloff and hard shadows. The room is closed: every ray from inside meets a
// surface, so there is no sky and every pixel is opaque. World units, z up; radiance linear.
#include <vector>

#include "synth/tracer.h"
#include "synth/world.h"
#include "util/vec3.h"

namespace ablenerf::synth {

// The room's inside: floor z = 0, ceiling z = 2.6, walls at x = +-2.5 and y = +-2.0.
constexpr Vec3 kRoomMin{-2.5, -2.0, 0.0}, kRoomMax{2.5, 2.0, 2.6};

// An axis-aligned box of furniture.
struct Box {
  const char* name;
  Vec3 lo, hi;
};

struct PointLight {
  const char* name;
  Vec3 position;
  Vec3 intensity;  // linear; irradiance intensity * cos / distance^2 on a surface
};

// Objects, in the order of Hit::object: the room's six faces (kRoomFaceNames), the furniture boxes
// (room_furniture()), then the ball (room_ball()).
constexpr int kRoomFaces = 6;
constexpr const char* kRoomFaceNames[kRoomFaces] = {"floor",     "ceiling",    "wall_west",
                                                    "wall_east", "wall_south", "wall_north"};
const std::vector<Box>& room_furniture();
const Sphere& room_ball();  // diffuse, resting on the floor
int room_object_count();
const char* room_object_name(int object);

// Lighting: radiance = albedo * (ambient + sum over lights of intensity * max(0, cos) /
// max(d^2, kRoomLightMinDistance^2) * visible), visible = 0 when the furniture or the ball blocks
// the segment to the light (walls cannot: the room is convex and the lights are inside it).
const std::vector<PointLight>& room_lights();
Vec3 room_ambient();
constexpr double kRoomLightMinDistance = 0.75;  // the falloff stops growing nearer than this

// Smallest t > t_min at which the ray meets the box's surface (from outside or inside), or +infinity.
double intersect_box(const Box& b, const Ray& r, double t_min);
// The first object along the ray (t > t_min). From inside the room it always hits something.
Hit intersect_room(const Ray& r, double t_min = 0.0);
// The unit normal of `object` at its surface point p, facing into the room (walls) or out of the
// object (furniture, ball).
Vec3 room_normal(int object, const Vec3& p);
// The albedo of `object` at its surface point p, every channel in [kRoomAlbedoMin, kRoomAlbedoMax].
Vec3 room_albedo(int object, const Vec3& p);
constexpr double kRoomAlbedoMin = 0.05, kRoomAlbedoMax = 0.9;
// Radiance arriving along the ray (0 on a miss, which only a ray from outside the room can have).
Vec3 trace_room(const Ray& r, int depth = 0);

// intersect_room and trace_room, for render_view.
SceneTracer room_tracer();

}  // namespace ablenerf::synth
