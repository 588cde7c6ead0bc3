#include "data/colmap_model.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <system_error>
#include <unordered_set>

#include "data/colmap_model_internal.h"
#include "util/errors.h"
#include "util/fs.h"

namespace fs = std::filesystem;

namespace ablenerf {

namespace colmap_detail {

void check_camera(const ColmapCamera& c, const std::string& origin, const std::string& where) {
  if (c.width < 1 || c.width > kMaxSide)
    throw InputError(origin, where + ": width", std::to_string(c.width) + " is not in [1, 1048576]");
  if (c.height < 1 || c.height > kMaxSide)
    throw InputError(origin, where + ": height", std::to_string(c.height) + " is not in [1, 1048576]");
  for (size_t k = 0; k < c.params.size(); ++k)
    if (!std::isfinite(c.params[k]))
      throw InputError(origin, where + ": params[" + std::to_string(k) + "]", "non-finite value");
}

void check_image(ColmapImage& im, const std::string& origin, const std::string& where) {
  double largest = 0;
  for (const double q : im.qvec) {
    if (!std::isfinite(q)) throw InputError(origin, where + ": qvec", "non-finite value");
    largest = std::max(largest, std::abs(q));
  }
  // Scaled by the largest component first, so that neither tiny nor huge values under- or
  // overflow when squared.
  double sum = 0;
  if (largest > 0)
    for (const double q : im.qvec) sum += (q / largest) * (q / largest);
  const double root = std::sqrt(sum);
  if (!(largest * root > kMinQuatNorm))
    throw InputError(origin, where + ": qvec", "not a rotation (length below 1e-6)");
  for (double& q : im.qvec) q = (q / largest) / root;
  for (const double t : im.tvec)
    if (!std::isfinite(t)) throw InputError(origin, where + ": tvec", "non-finite value");
  if (im.name.empty()) throw InputError(origin, where + ": name", "empty");
  if (im.name.find('\0') != std::string::npos) throw InputError(origin, where + ": name", "holds a NUL byte");
}

}  // namespace colmap_detail

using namespace colmap_detail;

const char* colmap_model_name(int model_id) {
  return model_id >= 0 && model_id < kNumCameraModels ? kCameraModels[model_id].name : "";
}

int colmap_model_params(const std::string& model) {
  for (const auto& m : kCameraModels)
    if (model == m.name) return m.params;
  return -1;
}

ColmapModel read_colmap_model(const std::string& dir) {
  ColmapModel m;
  m.dir = dir;
  const fs::path d(dir);
  const auto exists = [&](const std::string& name) {
    std::error_code ec;
    return fs::exists(d / name, ec);
  };
  if (exists("cameras.bin"))
    m.encoding = "bin";
  else if (exists("cameras.txt"))
    m.encoding = "txt";
  else
    throw InputError(dir, "cameras.bin|cameras.txt", "missing");
  const bool bin = m.encoding == "bin";
  const std::string cameras_name = "cameras." + m.encoding, images_name = "images." + m.encoding,
                    points_name = "points3D." + m.encoding;
  if (!exists(images_name)) throw InputError(dir, images_name, "missing");
  const std::string cameras_path = (d / cameras_name).string(), images_path = (d / images_name).string(),
                    points_path = (d / points_name).string();

  const std::string cameras_bytes = read_file(cameras_path);
  m.cameras = bin ? parse_cameras_bin(cameras_bytes, cameras_path) : parse_cameras_txt(cameras_bytes, cameras_path);
  const std::string images_bytes = read_file(images_path);
  m.images = bin ? parse_images_bin(images_bytes, images_path) : parse_images_txt(images_bytes, images_path);
  if (exists(points_name)) {
    const std::string points_bytes = read_file(points_path);
    m.points = bin ? parse_points3d_bin(points_bytes, points_path) : parse_points3d_txt(points_bytes, points_path);
  }

  std::unordered_set<uint32_t> camera_ids;
  for (const auto& c : m.cameras) camera_ids.insert(c.id);
  for (const auto& im : m.images)
    if (!camera_ids.count(im.camera_id))
      throw InputError(images_path, image_label(im.id, im.name) + ": camera_id",
                       "camera " + std::to_string(im.camera_id) + " is not in " + base_name(cameras_path));
  return m;
}

}  // namespace ablenerf
