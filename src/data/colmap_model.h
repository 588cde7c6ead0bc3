#pragma once
// A COLMAP sparse reconstruction (DIR/cameras, images, points3D in .bin or .txt), read directly
// and validated without LibTorch: colmap_capture.cpp turns it into a capture, fuzz/fuzz_colmap.cpp
// feeds it arbitrary bytes. The input is untrusted, so every read is bounds-checked, every record
// count is checked against the bytes left before any memory is reserved (a header claiming 2^60
// records fails at once), and every value that is used later is checked finite. Each refusal is
// an InputError naming the file and the record, e.g.
//   "sparse/0/images.bin: image 12 (IMG_0012.JPG): camera_id: camera 3 is not in cameras.bin".
#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace ablenerf {

struct ColmapCamera {
  uint32_t id = 0;
  std::string model;               // COLMAP's name, e.g. "PINHOLE"
  int model_id = -1;               // COLMAP's number, e.g. 1
  uint64_t width = 0, height = 0;  // in [1, 2^20]
  std::vector<double> params;      // exactly colmap_model_params(model) finite values
};

struct ColmapImage {
  uint32_t id = 0;
  std::array<double, 4> qvec{};  // w, x, y, z: world-to-camera rotation, normalised to unit length
  std::array<double, 3> tvec{};  // world-to-camera translation
  uint32_t camera_id = 0;
  std::string name;  // path below the capture's images/ folder; never empty, never holds '\0'
  // The 3D points this image observes, in the order of its 2D points; observations without a
  // point (id -1) are left out.
  std::vector<uint64_t> point3d_ids;
};

struct ColmapPoint {
  uint64_t id = 0;
  std::array<double, 3> xyz{};  // finite
  std::array<uint8_t, 3> rgb{};
  double error = 0;  // mean reprojection error in pixels, as written (not checked: nothing uses it)
};

struct ColmapModel {
  std::string dir;
  std::string encoding;  // "bin" | "txt"
  std::vector<ColmapCamera> cameras;
  std::vector<ColmapImage> images;
  std::vector<ColmapPoint> points;  // empty when the model has no points3D file
};

// Reads the model in `dir` (e.g. CAPTURE/sparse/0): the .bin files when cameras.bin exists, else
// the .txt files. points3D may be absent; a missing cameras or images file is an
// InputError(dir, "cameras.bin|cameras.txt" or "images.EXT", "missing"). Beyond what the parsers
// check, every image's camera must be in the cameras file.
ColmapModel read_colmap_model(const std::string& dir);

// The parsers, on a whole file held in memory (for the fuzzer and the tests). `origin` names the
// file in errors. Each checks what one file can: counts, sizes, finiteness, unique ids, names.
std::vector<ColmapCamera> parse_cameras_bin(const std::string& bytes, const std::string& origin);
std::vector<ColmapImage> parse_images_bin(const std::string& bytes, const std::string& origin);
std::vector<ColmapPoint> parse_points3d_bin(const std::string& bytes, const std::string& origin);
std::vector<ColmapCamera> parse_cameras_txt(const std::string& text, const std::string& origin);
std::vector<ColmapImage> parse_images_txt(const std::string& text, const std::string& origin);
std::vector<ColmapPoint> parse_points3d_txt(const std::string& text, const std::string& origin);

// The number of parameters of the COLMAP camera model called `model` (e.g. 4 for "PINHOLE"), -1
// when COLMAP has no such model.
int colmap_model_params(const std::string& model);

// The name of COLMAP's camera model number `model_id` (0 SIMPLE_PINHOLE ... 10
// THIN_PRISM_FISHEYE), "" when there is none.
const char* colmap_model_name(int model_id);

}  // namespace ablenerf
