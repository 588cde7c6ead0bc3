#pragma once
// What the COLMAP model readers share (colmap_model.cpp: the model and the checks;
// colmap_model_binary.cpp: the .bin files; colmap_model_text.cpp: the .txt files): COLMAP's
// camera-model table, the limits, record labels and the checks both encodings apply. Private to
// src/data.
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <limits>
#include <string>

#include "data/colmap_model.h"
#include "util/errors.h"

namespace ablenerf::colmap_detail {

// Longest excerpt of an input's text quoted in an error message.
inline constexpr size_t kColmapQuoteChars = 80;

// COLMAP's camera models, indexed by the model id its binary files store, with their parameter
// counts (the numbering of COLMAP's documentation; it has not changed since the format appeared).
struct CameraModelInfo {
  const char* name;
  int params;
};
inline constexpr CameraModelInfo kCameraModels[] = {
    {"SIMPLE_PINHOLE", 3},         // 0
    {"PINHOLE", 4},                // 1
    {"SIMPLE_RADIAL", 4},          // 2
    {"RADIAL", 5},                 // 3
    {"OPENCV", 8},                 // 4
    {"OPENCV_FISHEYE", 8},         // 5
    {"FULL_OPENCV", 12},           // 6
    {"FOV", 5},                    // 7
    {"SIMPLE_RADIAL_FISHEYE", 4},  // 8
    {"RADIAL_FISHEYE", 5},         // 9
    {"THIN_PRISM_FISHEYE", 12},    // 10
};
inline constexpr int kNumCameraModels = static_cast<int>(sizeof(kCameraModels) / sizeof(kCameraModels[0]));
inline constexpr size_t kFewestParams = 3;  // SIMPLE_PINHOLE

inline constexpr uint64_t kMaxSide = uint64_t{1} << 20;
// A 2D point without a 3D point: -1 as an int64 in both encodings.
inline constexpr uint64_t kNoPoint = std::numeric_limits<uint64_t>::max();
// Below this length a quaternion's direction is noise, not a rotation.
inline constexpr double kMinQuatNorm = 1e-6;
inline constexpr uint64_t kMaxU32 = std::numeric_limits<uint32_t>::max();
inline constexpr uint64_t kMaxU64 = std::numeric_limits<uint64_t>::max();

inline std::string image_label(uint32_t id, const std::string& name) {
  return "image " + std::to_string(id) + " (" + printable(name, kColmapQuoteChars) + ")";
}

inline std::string base_name(const std::string& path) { return std::filesystem::path(path).filename().string(); }

// The checks shared by both encodings. `where` names the record ("camera 3", "line 5: camera 3").
void check_camera(const ColmapCamera& c, const std::string& origin, const std::string& where);
// Checks the pose and name and scales qvec to unit length.
void check_image(ColmapImage& im, const std::string& origin, const std::string& where);

}  // namespace ablenerf::colmap_detail
