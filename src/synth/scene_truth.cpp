#include "synth/scene_truth.h"

#include <nlohmann/json.hpp>

#include "util/errors.h"
#include "util/json_file.h"

namespace ablenerf::synth {

std::vector<SphereTruth> read_scene_spheres(const std::string& scene_json) {
  return scene_spheres(read_json_file(scene_json), scene_json);
}

std::vector<SphereTruth> scene_spheres(const nlohmann::json& j, const std::string& scene_json) {
  if (!j.is_object() || !j.contains("objects") || !j["objects"].is_array())
    throw InputError(scene_json, "objects", "missing (not a scene.json written by `ablenerf synth`)");
  std::vector<SphereTruth> out;
  for (size_t i = 0; i < j["objects"].size(); ++i) {
    const auto& o = j["objects"][i];
    const std::string where = "objects[" + std::to_string(i) + "]";
    if (!o.is_object() || o.value("shape", "") != "sphere") continue;
    SphereTruth s;
    s.name = o.value("name", where);
    s.material = o.value("material", "");
    if (!o.contains("centre") || !o["centre"].is_array() || o["centre"].size() != 3 || !o.contains("radius") ||
        !o["radius"].is_number())
      throw InputError(scene_json, where, "a sphere needs centre [x, y, z] and radius");
    for (size_t a = 0; a < 3; ++a) s.centre[a] = o["centre"][a].get<double>();
    s.radius = o["radius"].get<double>();
    if (!(s.radius > 0)) throw InputError(scene_json, where + ".radius", "must be positive");
    out.push_back(s);
  }
  if (out.empty()) throw InputError(scene_json, "objects", "no sphere to score against");
  return out;
}

}  // namespace ablenerf::synth
