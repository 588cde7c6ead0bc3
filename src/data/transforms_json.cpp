#include "data/transforms_json.h"

#include "data/capture_formats.h"

#include "data/ply.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <optional>
#include <unordered_map>

#include "util/errors.h"
#include "util/fs.h"
#include "util/image_codec.h"
#include "util/json_file.h"

namespace fs = std::filesystem;
using nlohmann::json;

namespace ablenerf {

namespace {

// JSON has no non-finite numbers, but Python's json module writes NaN / Infinity / -Infinity and
// a literal like 1e999 overflows a double. Both are rewritten to the string "non-finite" so that
// the field that holds them can be named in the error (see is_nonfinite_marker).
const char* const kNonFinite = "\"non-finite\"";

std::string mark_nonfinite(const std::string& text) {
  std::string out;
  out.reserve(text.size());
  bool in_string = false;
  for (size_t i = 0; i < text.size();) {
    const char c = text[i];
    if (in_string) {
      out += c;
      if (c == '\\' && i + 1 < text.size())
        out += text[++i];
      else if (c == '"')
        in_string = false;
      ++i;
      continue;
    }
    if (c == '"') {
      in_string = true;
      out += c;
      ++i;
      continue;
    }
    bool matched = false;
    for (const char* tok : {"-Infinity", "Infinity", "NaN"}) {
      const size_t n = std::char_traits<char>::length(tok);
      if (text.compare(i, n, tok) == 0) {
        out += kNonFinite;
        i += n;
        matched = true;
        break;
      }
    }
    if (matched) continue;
    if (c == '-' || (c >= '0' && c <= '9')) {
      size_t j = i + 1;
      while (j < text.size() && (std::isdigit(static_cast<unsigned char>(text[j])) || text[j] == '.' ||
                                 text[j] == 'e' || text[j] == 'E' || text[j] == '+' || text[j] == '-'))
        ++j;
      const std::string num = text.substr(i, j - i);
      const double v = std::strtod(num.c_str(), nullptr);
      out += std::isfinite(v) ? num : std::string(kNonFinite);
      i = j;
      continue;
    }
    out += c;
    ++i;
  }
  return out;
}

bool is_nonfinite_marker(const json& v) { return v.is_string() && v.get<std::string>() == "non-finite"; }

json parse_json_file(const std::string& path) { return parse_json_text(mark_nonfinite(read_file(path)), path); }

double number_field(const json& j, const std::string& key, const std::string& file, const std::string& where) {
  const std::string field = where.empty() ? key : where + "." + key;
  if (!j.is_object() || !j.contains(key)) throw InputError(file, field, "missing");
  const json& v = j.at(key);
  if (is_nonfinite_marker(v)) throw InputError(file, field, "must be finite");
  if (!v.is_number()) throw InputError(file, field, "expected a number");
  const double d = v.get<double>();
  if (!std::isfinite(d)) throw InputError(file, field, "must be finite");
  return d;
}

// camera_angle_x (the horizontal field of view): in (0, pi), else the focal length 0.5 w / tan(a / 2)
// is infinite (a = 0) or not positive.
double angle_field(const json& j, const std::string& file) {
  const double a = number_field(j, "camera_angle_x", file, "");
  if (a <= 0 || a >= M_PI) throw InputError(file, "camera_angle_x", "must be in (0, pi)");
  return a;
}

// Largest image side accepted from json (w, h): far above any camera, small enough that
// w * h * channels cannot overflow and that the double -> int conversion is defined.
constexpr double kMaxImageSide = 1 << 20;

// An image size field (w or h): a whole number in [1, kMaxImageSide].
int size_field(const json& j, const std::string& key, const std::string& file) {
  const double v = number_field(j, key, file, "");
  if (!(v >= 1 && v <= kMaxImageSide) || v != std::floor(v))
    throw InputError(
        file, key, "image size must be a whole number in [1, " + std::to_string(static_cast<int>(kMaxImageSide)) + "]");
  return static_cast<int>(v);
}

// Tolerances of the pose checks: json poses are written with ~6-7 significant digits.
constexpr double kLastRowTolerance = 1e-4;  // |last row - [0, 0, 0, 1]|_1

}  // namespace

Pose34 parse_pose_matrix(const json& m, const std::string& file, const std::string& field, double (&out)[3][4]) {
  if (!m.is_array() || (m.size() != 4 && m.size() != 3))
    throw InputError(file, field, "expected a 4x4 (or 3x4) matrix");
  double a[4][4] = {{0}};
  for (size_t r = 0; r < m.size(); ++r) {
    if (!m[r].is_array() || m[r].size() != 4) throw InputError(file, field, "expected rows of 4 numbers");
    for (size_t c = 0; c < 4; ++c) {
      if (is_nonfinite_marker(m[r][c])) throw InputError(file, field, "non-finite value");
      if (!m[r][c].is_number()) throw InputError(file, field, "expected numbers");
      a[r][c] = m[r][c].get<double>();
      if (!std::isfinite(a[r][c])) throw InputError(file, field, "non-finite value");
    }
  }
  if (m.size() == 4) {
    const double d = std::abs(a[3][0]) + std::abs(a[3][1]) + std::abs(a[3][2]) + std::abs(a[3][3] - 1);
    if (d > kLastRowTolerance) throw InputError(file, field, "last row must be [0, 0, 0, 1]");
  }
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) out[r][c] = a[r][c];
  return checked_pose(out, file, field);
}

namespace {

Pose34 parse_pose(const json& m, const std::string& file, const std::string& field) {
  double unused[3][4];
  return parse_pose_matrix(m, file, field, unused);
}

std::vector<CaptureFrame> parse_frames(const json& j, const std::string& root, const std::string& file, bool add_png) {
  if (!j.contains("frames")) throw InputError(file, "frames", "missing");
  const json& frames = j.at("frames");
  if (!frames.is_array()) throw InputError(file, "frames", "expected an array");
  if (frames.empty()) throw InputError(file, "frames", "no frames");
  std::vector<CaptureFrame> out;
  for (size_t i = 0; i < frames.size(); ++i) {
    const std::string where = "frames[" + std::to_string(i) + "]";
    const json& fr = frames[i];
    if (!fr.is_object()) throw InputError(file, where, "expected an object");
    if (!fr.contains("file_path") || !fr.at("file_path").is_string())
      throw InputError(file, where + ".file_path", "missing or not a string");
    if (!fr.contains("transform_matrix")) throw InputError(file, where + ".transform_matrix", "missing");
    CaptureFrame f;
    f.field = where + ".file_path";
    f.image = resolve_in_root(root, fr.at("file_path").get<std::string>(), file, f.field, add_png);
    f.pose = parse_pose(fr.at("transform_matrix"), file, where + ".transform_matrix");
    if (fr.contains("depth_file_path")) {
      if (!fr.at("depth_file_path").is_string())
        throw InputError(file, where + ".depth_file_path", "expected a string");
      f.depth =
          resolve_in_root(root, fr.at("depth_file_path").get<std::string>(), file, where + ".depth_file_path", false);
    }
    if (fr.contains("mask_path")) {  // nerfstudio: white keeps
      if (!fr.at("mask_path").is_string()) throw InputError(file, where + ".mask_path", "expected a string");
      f.mask_field = where + ".mask_path";
      f.mask = resolve_in_root(root, fr.at("mask_path").get<std::string>(), file, f.mask_field, false);
    } else {  // instant-ngp: dynamic_mask_<image stem>.png beside the image marks what to leave out
      const fs::path dyn =
          fs::path(f.image).parent_path() / ("dynamic_mask_" + fs::path(f.image).stem().string() + ".png");
      if (fs::is_regular_file(dyn)) {
        f.mask = dyn.string();
        f.mask_keeps_set = false;
        f.mask_field = where + " (dynamic mask)";
      }
    }
    out.push_back(std::move(f));
  }
  return out;
}

// A number from a frame, else from the file's top level, else `fallback`; `where` names the frame.
std::optional<double> number_in(const json& frame, const json& top, const char* key, const std::string& file,
                                const std::string& where) {
  if (frame.is_object() && frame.contains(key)) return number_field(frame, key, file, where);
  if (top.contains(key)) return number_field(top, key, file, "");
  return std::nullopt;
}

const json* key_in(const json& frame, const json& top, const char* key) {
  if (frame.is_object() && frame.contains(key)) return &frame.at(key);
  if (top.contains(key)) return &top.at(key);
  return nullptr;
}

// One frame's camera from instant-ngp / nerfstudio keys (per-frame keys override the file's):
// fl_x/fl_y or camera_angle_x/camera_angle_y, cx/cy (default: the centre), w/h (default: the image
// header), k1 k2 k3 k4 p1 p2, camera_model (PINHOLE, SIMPLE_PINHOLE, OPENCV, OPENCV_FISHEYE) or
// instant-ngp's is_fisheye.
Intrinsics frame_camera(const json& fr, const json& top, const std::string& image, const std::string& file,
                        const std::string& where) {
  Intrinsics k;
  const auto w = number_in(fr, top, "w", file, where), h = number_in(fr, top, "h", file, where);
  if (w && h) {
    const json& wj = fr.contains("w") ? fr : top;
    const json& hj = fr.contains("h") ? fr : top;
    k.width = size_field(wj, "w", file);
    k.height = size_field(hj, "h", file);
  } else {
    const auto hw = image_size(image);  // instant-ngp allows w/h to be left out
    k.height = hw.first;
    k.width = hw.second;
  }
  const auto flx = number_in(fr, top, "fl_x", file, where), fly = number_in(fr, top, "fl_y", file, where);
  const auto ax = number_in(fr, top, "camera_angle_x", file, where),
             ay = number_in(fr, top, "camera_angle_y", file, where);
  if (flx)
    k.fx = *flx;
  else if (ax)
    k.fx = 0.5 * k.width / std::tan(0.5 * *ax);
  else
    throw InputError(file, where.empty() ? "fl_x" : where + ".fl_x", "missing (nor camera_angle_x)");
  if (fly)
    k.fy = *fly;
  else if (ay)
    k.fy = 0.5 * k.height / std::tan(0.5 * *ay);
  else
    k.fy = k.fx;
  if (ax && !(*ax > 0 && *ax < M_PI)) throw InputError(file, "camera_angle_x", "must be in (0, pi)");
  if (ay && !(*ay > 0 && *ay < M_PI)) throw InputError(file, "camera_angle_y", "must be in (0, pi)");
  check_focal(k.fx, file, where + "fl_x");
  check_focal(k.fy, file, where + "fl_y");
  k.cx = number_in(fr, top, "cx", file, where).value_or(0.5 * k.width);
  k.cy = number_in(fr, top, "cy", file, where).value_or(0.5 * k.height);
  static const char* const names[kLensCoeffs] = {"k1", "k2", "k3", "k4", "p1", "p2"};
  for (int c = 0; c < kLensCoeffs; ++c)
    k.dist[static_cast<size_t>(c)] = number_in(fr, top, names[c], file, where).value_or(0.0);
  std::string model = "";
  if (const json* m = key_in(fr, top, "camera_model")) {
    if (!m->is_string()) throw InputError(file, "camera_model", "expected a string");
    model = m->get<std::string>();
  }
  if (const json* f = key_in(fr, top, "is_fisheye"); f && f->is_boolean() && f->get<bool>()) model = "OPENCV_FISHEYE";
  if (model == "OPENCV_FISHEYE") {
    k.model = LensModel::Fisheye;
    if (k.dist[kP1] != 0 || k.dist[kP2] != 0)
      throw InputError(file, "p1", "a fisheye lens has no tangential coefficients (p1, p2)");
  } else if (model.empty() || model == "OPENCV" || model == "PINHOLE" || model == "SIMPLE_PINHOLE" ||
             model == "SIMPLE_RADIAL" || model == "RADIAL") {
    if (k.dist[kK4] != 0) throw InputError(file, "k4", "k4 belongs to the fisheye model (camera_model OPENCV_FISHEYE)");
    k.model = k.distorted() ? LensModel::RadialTangential : LensModel::Pinhole;
    if ((model == "PINHOLE" || model == "SIMPLE_PINHOLE") && k.distorted())
      throw InputError(file, "camera_model", model + " with distortion coefficients (use OPENCV)");
  } else {
    throw InputError(
        file, "camera_model",
        "'" + model + "' is not supported (PINHOLE, SIMPLE_PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, OPENCV_FISHEYE)");
  }
  for (int c = 0; c < kLensCoeffs; ++c)
    if (std::abs(k.dist[static_cast<size_t>(c)]) > 1e3) throw InputError(file, names[c], "implausibly large");
  return k;
}

// nerfstudio's own split: lists of image paths ("train_filenames", "val_filenames",
// "test_filenames") relative to the folder.
bool has_own_split(const json& j) { return j.contains("train_filenames") || j.contains("test_filenames"); }

}  // namespace

// Blender: one json per split sharing camera_angle_x; the image size comes from the first PNG.
bool is_blender_capture(const std::string& root) {
  return fs::exists(fs::path(root) / "transforms_train.json") || fs::exists(fs::path(root) / "transforms_test.json");
}

void read_blender_capture(const std::string& root, const std::vector<std::string>& splits, int /*downscale*/,
                          Capture& out) {
  out.format = "blender";
  out.synthetic = true;
  double angle = -1;
  std::string first_file;
  for (const char* name : {"train", "val", "test"}) {
    const std::string file = (fs::path(root) / ("transforms_" + std::string(name) + ".json")).string();
    if (!fs::exists(file) || !split_wanted(splits, name)) continue;
    const json j = parse_json_file(file);
    if (!j.is_object()) throw InputError(file, "", "expected a JSON object");
    const double a = angle_field(j, file);
    if (angle < 0) {
      angle = a;
      first_file = file;
    } else if (std::abs(a - angle) > 1e-9) {
      throw InputError(file, "camera_angle_x", "differs from " + first_file + " (splits must share one camera)");
    }
    auto frames = parse_frames(j, root, file, true);
    // nerf_synthetic's test frames keep their depth beside the image (data/depth_file.h reads them).
    for (auto& f : frames) {
      if (!f.depth.empty()) continue;
      f.depth = blender_depth_file(f.image);
      if (!f.depth.empty()) f.depth_format = DepthFormat::BlenderPng;
    }
    out.splits.push_back({name, file, std::move(frames)});
  }
  if (out.splits.empty()) throw InputError(root, "transforms_*.json", "no split selected or present");
  const auto hw = image_size(out.splits.front().frames.front().image);
  out.height = hw.first;
  out.width = hw.second;
  Intrinsics k;
  k.width = out.width;
  k.height = out.height;
  k.fx = k.fy = 0.5 * static_cast<double>(out.width) / std::tan(0.5 * angle);
  k.cx = 0.5 * out.width;
  k.cy = 0.5 * out.height;
  for (auto& s : out.splits)
    for (auto& f : s.frames) f.camera = k;
}

// instant-ngp / nerfstudio: one transforms.json, cameras per file or per frame.
bool is_transforms_capture(const std::string& root) { return fs::exists(fs::path(root) / "transforms.json"); }

void read_transforms_capture(const std::string& root, const std::vector<std::string>& splits, int downscale,
                             Capture& out) {
  const std::string file = (fs::path(root) / "transforms.json").string();
  const json j = parse_json_file(file);
  if (!j.is_object()) throw InputError(file, "", "expected a JSON object");
  out.format =
      j.contains("camera_model") || j.contains("applied_transform") || has_own_split(j) ? "nerfstudio" : "instant-ngp";
  auto frames = parse_frames(j, root, file, false);
  const json& jf = j.at("frames");
  for (size_t i = 0; i < frames.size(); ++i) {
    const std::string where = "frames[" + std::to_string(i) + "].";
    frames[i].camera = frame_camera(jf[i], j, frames[i].image, file, where);
    if (i == 0) {
      out.width = frames[0].camera.width;
      out.height = frames[0].camera.height;
    } else if (frames[i].camera.width != out.width || frames[i].camera.height != out.height) {
      throw InputError(file, where + "w",
                       "frame size " + std::to_string(frames[i].camera.width) + "x" +
                           std::to_string(frames[i].camera.height) + " differs from the first frame's " +
                           std::to_string(out.width) + "x" + std::to_string(out.height));
    }
  }
  if (j.contains("aabb_scale")) {
    out.aabb_scale = number_field(j, "aabb_scale", file, "");
    out.notes.push_back("aabb_scale " + std::to_string(static_cast<int>(out.aabb_scale)));
  }
  // nerfstudio's sparse point cloud (ns-process-data writes it, in the poses' frame): the scene's
  // near bound comes from it as from a COLMAP model's points.
  if (j.contains("ply_file_path")) {
    if (!j.at("ply_file_path").is_string()) throw InputError(file, "ply_file_path", "expected a string");
    const std::string rel = j.at("ply_file_path").get<std::string>();
    if (fs::exists(fs::path(root) / rel)) {
      out.points = read_ply_points(resolve_in_root(root, rel, file, "ply_file_path"));
      out.notes.push_back(std::to_string(out.points.size()) + " sparse points from " + rel);
    } else {
      out.notes.push_back("ply_file_path " + rel + " not found: near/far from the cameras");
    }
  }
  for (const char* k : {"scale", "offset", "applied_transform"})
    if (j.contains(k))
      out.notes.push_back(std::string(k) + " present (poses used as written; ablenerf normalises the scene itself)");
  // Each frame by its image's canonical path (what parse_frames resolved), for the capture's own
  // split, before pre-downscaled copies replace the paths.
  std::unordered_map<std::string, size_t> frame_of;
  for (size_t i = 0; i < frames.size(); ++i) frame_of.emplace(frames[i].image, i);
  for (auto& f : frames) {
    const std::string small = resolve_downscaled(root, f.image, downscale);
    if (!small.empty()) f.image = small, f.prescaled = true;
  }
  if (has_own_split(j)) {
    // The capture's own split, by image path.
    std::vector<std::pair<std::string, std::string>> lists{
        {"train", "train_filenames"}, {"val", "val_filenames"}, {"test", "test_filenames"}};
    for (const auto& [name, key] : lists) {
      if (!j.contains(key) || !split_wanted(splits, name)) continue;
      const json& names = j.at(key);
      if (!names.is_array()) throw InputError(file, key, "expected an array of image paths");
      CaptureSplit sp{name, file, {}};
      for (size_t i = 0; i < names.size(); ++i) {
        if (!names[i].is_string()) throw InputError(file, key + "[" + std::to_string(i) + "]", "expected a string");
        const std::string want =
            resolve_in_root(root, names[i].get<std::string>(), file, key + "[" + std::to_string(i) + "]");
        const auto it = frame_of.find(want);
        if (it == frame_of.end())
          throw InputError(file, key + "[" + std::to_string(i) + "]", "no frame has this file_path");
        sp.frames.push_back(frames[it->second]);
      }
      if (!sp.frames.empty()) out.splits.push_back(std::move(sp));
    }
    out.notes.push_back("split: the capture's own (train_filenames / test_filenames)");
    return;
  }
  // instant-ngp keeps the json's frame order; every 8th of it is held out.
  split_every_eighth(std::move(frames), splits, file, FrameOrder::AsGiven, out);
}

CameraJson read_camera_json(const std::string& path, int width, int height) {
  const json j = parse_json_file(path);
  if (!j.is_object()) throw InputError(path, "", "expected a JSON object");
  if (!j.contains("frames") || !j.at("frames").is_array() || j.at("frames").empty())
    throw InputError(path, "frames", "missing or empty");
  const int w = j.contains("w") ? size_field(j, "w", path) : width;
  const int h = j.contains("h") ? size_field(j, "h", path) : height;
  if (w <= 0 || h <= 0) throw InputError(path, "w", "image size unknown: give --width/--height or w/h");
  double fx;
  if (j.contains("fl_x"))
    fx = number_field(j, "fl_x", path, "");
  else
    fx = 0.5 * w / std::tan(0.5 * angle_field(j, path));
  const double fy = j.contains("fl_y") ? number_field(j, "fl_y", path, "") : fx;
  check_focal(fx, path, j.contains("fl_x") ? "fl_x" : "camera_angle_x");
  check_focal(fy, path, j.contains("fl_y") ? "fl_y" : "fl_x");
  const double cx = j.contains("cx") ? number_field(j, "cx", path, "") : 0.5 * w;
  const double cy = j.contains("cy") ? number_field(j, "cy", path, "") : 0.5 * h;
  const double sx = width > 0 ? static_cast<double>(width) / w : 1.0;
  const double sy = height > 0 ? static_cast<double>(height) / h : sx;
  CameraJson cam;
  cam.fx = fx * sx;
  cam.fy = fy * sy;
  cam.cx = cx * sx;
  cam.cy = cy * sy;
  cam.width = width > 0 ? width : w;
  // Only the width was given: the height follows the json's aspect ratio. Bounded before the
  // double -> int conversion (undefined when out of range).
  const double scaled_h = h * sy;
  if (height <= 0 && scaled_h > kMaxImageSide)
    throw InputError(path, "h", "rescaled image height exceeds " + std::to_string(static_cast<int>(kMaxImageSide)));
  cam.height = height > 0 ? height : static_cast<int>(scaled_h);
  const json& frames = j.at("frames");
  for (size_t i = 0; i < frames.size(); ++i) {
    const std::string where = "frames[" + std::to_string(i) + "].transform_matrix";
    if (!frames[i].is_object() || !frames[i].contains("transform_matrix")) throw InputError(path, where, "missing");
    cam.poses.push_back(parse_pose(frames[i].at("transform_matrix"), path, where));
  }
  return cam;
}

}  // namespace ablenerf
