#pragma once
// The JSON capture formats behind capture.h's registry (Blender transforms_{train,val,test}.json;
// instant-ngp / nerfstudio transforms.json: read through read_capture), and camera lists for
// rendering read from the same JSON. fuzz/fuzz_transforms.cpp fuzzes the readers. Every refusal is
// an InputError naming the file and the field.
#include <nlohmann/json.hpp>

#include <string>
#include <vector>

#include "data/capture.h"

namespace ablenerf {

// A camera list for rendering: poses and pinhole intrinsics, no image paths.
struct CameraJson {
  double fx = 0, fy = 0, cx = 0, cy = 0;
  int width = 0, height = 0;
  std::vector<Pose34> poses;  // at least one
};

// A camera-to-world matrix as the transforms formats write it: 3x4, or 4x4 with the last row
// [0, 0, 0, 1], finite and rigid (checked_pose). Fills `out` (row-major, double precision) and returns
// the pose as a Pose34; an InputError naming file and field otherwise.
Pose34 parse_pose_matrix(const nlohmann::json& m, const std::string& file, const std::string& field,
                         double (&out)[3][4]);

// Reads a Blender/transforms json as a camera list. `width`/`height` > 0 rescale the intrinsics
// to that image size; without them the json must give w and h.
CameraJson read_camera_json(const std::string& path, int width = 0, int height = 0);

}  // namespace ablenerf
