#pragma once
// A COLMAP sparse model (cameras, images, points3D; .bin or .txt), read directly and validated
// without LibTorch (fuzzed): every count is checked against the bytes left before memory is
// reserved, every value for finiteness. Refusals are InputErrors naming the file and the record.
#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace ablenerf {

struct ColmapCamera {
  uint32_t id = 0;
  std::string model;
  int model_id = -1;
  uint64_t width = 0, height = 0;
  std::vector<double> params;
};

struct ColmapImage {
  uint32_t id = 0;
  std::array<double, 4> qvec{};  // w, x, y, z: world-to-camera rotation (normalised)
  std::array<double, 3> tvec{};
  uint32_t camera_id = 0;
  std::string name;
};

struct ColmapPoint {
  uint64_t id = 0;
  std::array<double, 3> xyz{};
};

struct ColmapModel {
  std::string dir, encoding;  // "bin" | "txt"
  std::vector<ColmapCamera> cameras;
  std::vector<ColmapImage> images;
  std::vector<ColmapPoint> points;
};

// Reads DIR/{cameras,images,points3D}.bin, else the .txt files; points3D may be absent.
ColmapModel read_colmap_model(const std::string& dir);

std::vector<ColmapCamera> parse_cameras_bin(const std::string& bytes, const std::string& origin);
std::vector<ColmapImage> parse_images_bin(const std::string& bytes, const std::string& origin);
std::vector<ColmapPoint> parse_points3d_bin(const std::string& bytes, const std::string& origin);
std::vector<ColmapCamera> parse_cameras_txt(const std::string& text, const std::string& origin);
std::vector<ColmapImage> parse_images_txt(const std::string& text, const std::string& origin);
std::vector<ColmapPoint> parse_points3d_txt(const std::string& text, const std::string& origin);

// COLMAP's camera models by id: name and parameter count ("" / -1 when unknown).
const char* colmap_model_name(int model_id);
int colmap_model_params(const std::string& model);

}  // namespace ablenerf
