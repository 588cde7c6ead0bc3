#include "synth/room_camera.h"

#include <cmath>
#include <random>

namespace ablenerf::synth {

namespace {

constexpr uint64_t kTestSeedSalt = 0x3c6ef372fe94f82bULL;  // the test views' stream, apart from the train views'

std::vector<Camera> draw_cameras(int count, int res, std::mt19937_64& rng) {
  std::vector<Camera> cams;
  cams.reserve(static_cast<size_t>(count));
  for (int k = 0; k < count; ++k) {
    const double yaw = 2.0 * M_PI * unit_uniform(rng);
    const double pitch_deg = kRoomMinPitchDeg + (kRoomMaxPitchDeg - kRoomMinPitchDeg) * unit_uniform(rng);
    const double pitch = pitch_deg * M_PI / 180.0;
    // Uniform by area over the half disc in front: radius sqrt-distributed, angle within 90 degrees of the yaw.
    const double r = kRoomCameraRadius * std::sqrt(unit_uniform(rng));
    const double angle = yaw + M_PI * (unit_uniform(rng) - 0.5);
    const double z = kRoomCameraMinHeight + (kRoomCameraMaxHeight - kRoomCameraMinHeight) * unit_uniform(rng);
    cams.push_back(look_along({r * std::cos(angle), r * std::sin(angle), z}, yaw, pitch, res));
  }
  return cams;
}

}  // namespace

Camera look_along(const Vec3& centre, double yaw, double pitch, int res) {
  const Vec3 forward{std::cos(pitch) * std::cos(yaw), std::cos(pitch) * std::sin(yaw), std::sin(pitch)};
  return upright_camera(centre, -forward, res, kRoomCameraAngleX);
}

std::vector<Camera> room_train_cameras(int count, int res, uint64_t seed) {
  std::mt19937_64 rng(seed);
  return draw_cameras(count, res, rng);
}

std::vector<Camera> room_test_cameras(int count, int res, uint64_t seed) {
  std::mt19937_64 rng(seed ^ kTestSeedSalt);
  return draw_cameras(count, res, rng);
}

}  // namespace ablenerf::synth
