// A COLMAP reconstruction as a capture: cameras (PINHOLE, SIMPLE_PINHOLE, SIMPLE_RADIAL, RADIAL,
// OPENCV, OPENCV_FISHEYE) mapped onto the lens models of camera.h, world-to-camera poses in OpenCV
// axes turned into camera-to-world in the project's OpenGL axes, images from ROOT/images/, the
// sparse points kept for the scene's bounds. Torch-free (fuzzed with the COLMAP reader).
#include <cmath>
#include <filesystem>
#include <map>

#include "data/capture_formats.h"
#include "data/colmap_model.h"
#include "util/errors.h"

namespace fs = std::filesystem;

namespace ablenerf {

namespace {

Intrinsics colmap_camera(const ColmapCamera& c, const std::string& file) {
  Intrinsics k;
  k.width = static_cast<int>(c.width);
  k.height = static_cast<int>(c.height);
  const auto& p = c.params;
  const std::string where = "camera " + std::to_string(c.id);
  const auto need = [&](size_t n) {
    if (p.size() != n) throw InputError(file, where, c.model + " needs " + std::to_string(n) + " parameters");
  };
  if (c.model == "SIMPLE_PINHOLE") {
    need(3);
    k.fx = k.fy = p[0], k.cx = p[1], k.cy = p[2];
  } else if (c.model == "PINHOLE") {
    need(4);
    k.fx = p[0], k.fy = p[1], k.cx = p[2], k.cy = p[3];
  } else if (c.model == "SIMPLE_RADIAL" || c.model == "RADIAL") {
    need(c.model == "RADIAL" ? 5 : 4);
    k.fx = k.fy = p[0], k.cx = p[1], k.cy = p[2];
    k.dist[kK1] = p[3];
    if (c.model == "RADIAL") k.dist[kK2] = p[4];
    k.model = LensModel::RadialTangential;
  } else if (c.model == "OPENCV") {
    need(8);
    k.fx = p[0], k.fy = p[1], k.cx = p[2], k.cy = p[3];
    k.dist[kK1] = p[4], k.dist[kK2] = p[5], k.dist[kP1] = p[6], k.dist[kP2] = p[7];
    k.model = LensModel::RadialTangential;
  } else if (c.model == "OPENCV_FISHEYE") {
    need(8);
    k.fx = p[0], k.fy = p[1], k.cx = p[2], k.cy = p[3];
    for (int i = 0; i < 4; ++i) k.dist[static_cast<size_t>(kK1 + i)] = p[static_cast<size_t>(4 + i)];
    k.model = LensModel::Fisheye;
  } else {
    throw InputError(file, where + ": model",
                     c.model +
                         " is not supported (PINHOLE, SIMPLE_PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, "
                         "OPENCV_FISHEYE; or undistort with `colmap image_undistorter`)");
  }
  if (!(k.fx > 0 && k.fy > 0)) throw InputError(file, where, "focal length must be positive");
  return k;
}

// The COLMAP model folder of `root`, "" when none.
std::string colmap_dir(const std::string& root) {
  for (const char* sub : {"sparse/0", "sparse", "colmap/sparse/0", ""}) {
    const fs::path d = fs::path(root) / sub;
    if (fs::exists(d / "cameras.bin") || fs::exists(d / "cameras.txt")) return d.string();
  }
  return "";
}

}  // namespace

bool is_colmap_capture(const std::string& root) { return !colmap_dir(root).empty(); }

void read_colmap_capture(const std::string& root, const std::vector<std::string>& splits, int downscale, Capture& out) {
  const std::string model_dir = colmap_dir(root);
  const ColmapModel m = read_colmap_model(model_dir);
  out.format = "colmap";
  const std::string cam_file = (fs::path(model_dir) / ("cameras." + m.encoding)).string();
  const std::string img_file = (fs::path(model_dir) / ("images." + m.encoding)).string();
  std::map<uint32_t, Intrinsics> cams;
  for (const auto& c : m.cameras) cams[c.id] = colmap_camera(c, cam_file);
  if (m.images.empty()) throw InputError(img_file, "images", "no registered images");
  std::vector<CaptureFrame> frames;
  for (const auto& im : m.images) {
    const std::string where = "image " + std::to_string(im.id) + " (" + im.name + ")";
    CaptureFrame f;
    f.field = where;
    f.image = resolve_in_root(root, "images/" + im.name, img_file, where);
    const auto it = cams.find(im.camera_id);
    if (it == cams.end()) throw InputError(img_file, where + ": camera_id", "not in the cameras file");
    f.camera = it->second;
    if (frames.empty()) {
      out.width = f.camera.width, out.height = f.camera.height;
    } else if (f.camera.width != out.width || f.camera.height != out.height) {
      throw InputError(cam_file, "camera " + std::to_string(im.camera_id),
                       "image size " + std::to_string(f.camera.width) + "x" + std::to_string(f.camera.height) +
                           " differs from " + std::to_string(out.width) + "x" + std::to_string(out.height) +
                           " (every image of a capture must have one size)");
    }
    // World-to-camera rotation from the unit quaternion (w, x, y, z), then c2w = [R^T | -R^T t],
    // with the camera's y and z axes flipped from OpenCV (y down, z forward) to OpenGL.
    const double w = im.qvec[0], x = im.qvec[1], y = im.qvec[2], z = im.qvec[3];
    const double n = std::sqrt(w * w + x * x + y * y + z * z);
    const double qw = w / n, qx = x / n, qy = y / n, qz = z / n;
    const double R[3][3] = {{1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy)},
                            {2 * (qx * qy + qw * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qw * qx)},
                            {2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy)}};
    double c2w[3][4];
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) c2w[r][c] = R[c][r] * (c == 0 ? 1.0 : -1.0);
      c2w[r][3] = -(R[0][r] * im.tvec[0] + R[1][r] * im.tvec[1] + R[2][r] * im.tvec[2]);
    }
    f.pose = checked_pose(c2w, img_file, where);
    f.mask = mask_in_folder(root, f.image, where);
    f.mask_field = "masks/";
    const std::string small = resolve_downscaled(root, f.image, downscale);
    if (!small.empty()) f.image = small, f.prescaled = true;
    frames.push_back(std::move(f));
  }
  for (const auto& p : m.points) out.points.push_back(p.xyz);
  out.notes.push_back("COLMAP model " + model_dir + " (" + m.encoding + "): " + std::to_string(m.cameras.size()) +
                      " camera(s), " + std::to_string(m.images.size()) + " images, " + std::to_string(m.points.size()) +
                      " points");
  split_every_eighth(std::move(frames), splits, img_file, FrameOrder::ByImageName, out);
}

}  // namespace ablenerf
