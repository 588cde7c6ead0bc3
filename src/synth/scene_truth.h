#pragma once
// The objects a synth scene.json records (scene.cpp writes it), read back by what scores against
// them: the exported geometry (geometry/surface_score.h) and the refined cameras' reprojection over
// the objects' box (`ablenerf metrics --cameras`).
#include <array>
#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

namespace ablenerf::synth {

struct SphereTruth {
  std::string name, material;
  std::array<double, 3> centre{};
  double radius = 0;
};

// The spheres of a synth scene.json ("objects" of shape "sphere"); InputError naming the file and
// field otherwise, and when there is none.
std::vector<SphereTruth> read_scene_spheres(const std::string& scene_json);
// The same from the file's parsed JSON (`scene_json` names the file in errors).
std::vector<SphereTruth> scene_spheres(const nlohmann::json& scene, const std::string& scene_json);

}  // namespace ablenerf::synth
