#pragma once
// Cameras of the room scene (room.h): a phone held inside the room, at standing height somewhere
// near the middle, looking outward at the walls and furniture: what a capture of a room is. Poses
// follow the demo cameras' convention (camera.h: columns right, up, backwards; it looks down -z),
// with no roll (the right axis is horizontal).
#include <cstdint>
#include <vector>

#include "synth/camera.h"

namespace ablenerf::synth {

constexpr double kRoomCameraAngleX = 65.0 * M_PI / 180.0;  // a phone's main camera, horizontally
// The positions: uniform over a disc of radius kRoomCameraRadius around the room's vertical axis
// (x = y = 0), at heights uniform in [kRoomCameraMinHeight, kRoomCameraMaxHeight].
constexpr double kRoomCameraRadius = 0.6;
constexpr double kRoomCameraMinHeight = 1.2, kRoomCameraMaxHeight = 1.7;
// The directions: yaw uniform over the full turn, pitch uniform in [min, max] (degrees, up > 0).
constexpr double kRoomMinPitchDeg = -20.0, kRoomMaxPitchDeg = 10.0;

// A square res x res camera at `centre` looking along yaw (radians from +x towards +y) and pitch
// (radians above the horizontal), with the room's field of view and no roll.
Camera look_along(const Vec3& centre, double yaw, double pitch, int res);

// `count` views drawn from `seed` (std::mt19937_64, portable conversion to [0,1)): yaw and pitch
// as above, and the position uniform over the half of the disc that the camera faces (the angle
// of its position from the axis within 90 degrees of its yaw), so that every camera looks
// outward, away from the middle, while the positions of all the views still cover the whole disc
// uniformly. The train views use `seed`, the test views a stream of their own from it.
std::vector<Camera> room_train_cameras(int count, int res, uint64_t seed);
std::vector<Camera> room_test_cameras(int count, int res, uint64_t seed);

}  // namespace ablenerf::synth
