#include "data/transforms_json.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "util/errors.h"
#include "util/fs.h"
#include "util/png_codec.h"

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
      if (c == '\\' && i + 1 < text.size()) out += text[++i];
      else if (c == '"') in_string = false;
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

json parse_json_file(const std::string& path) {
  const std::string text = mark_nonfinite(read_file(path));
  try {
    return json::parse(text);
  } catch (const json::parse_error& e) {
    throw InputError(path, "byte " + std::to_string(e.byte), "invalid JSON");
  } catch (const json::exception& e) {
    // e.g. a number too large for a double (1e999): nlohmann reports it as out_of_range.
    throw InputError(path, "", std::string("invalid JSON (") + e.what() + ")");
  }
}

double number_field(const json& j, const std::string& key, const std::string& file,
                    const std::string& where) {
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

// A focal length in pixels: positive and finite, since every ray direction divides by it.
void check_focal(double f, const std::string& file, const std::string& field) {
  if (!(f > 0 && std::isfinite(f))) throw InputError(file, field, "must be positive");
}

// Largest image side accepted from json (w, h): far above any camera, small enough that
// w * h * channels cannot overflow and that the double -> int conversion is defined.
constexpr double kMaxImageSide = 1 << 20;

// An image size field (w or h): a whole number in [1, kMaxImageSide].
int size_field(const json& j, const std::string& key, const std::string& file) {
  const double v = number_field(j, key, file, "");
  if (!(v >= 1 && v <= kMaxImageSide) || v != std::floor(v))
    throw InputError(file, key, "image size must be a whole number in [1, " +
                                    std::to_string(static_cast<int>(kMaxImageSide)) + "]");
  return static_cast<int>(v);
}

// Tolerances of the pose checks: json poses are written with ~6-7 significant digits.
constexpr double kLastRowTolerance = 1e-4;  // |last row - [0, 0, 0, 1]|_1
constexpr double kRigidTolerance = 1e-3;    // max |R^T R - I|

// Pose (3,4 or 4,4 rows) -> the top 3x4, checked finite and rigid.
Pose34 parse_pose(const json& m, const std::string& file, const std::string& field) {
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
  // Rigid: columns of R orthonormal, det +1.
  double worst = 0;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      double dot = 0;
      for (int k = 0; k < 3; ++k) dot += a[k][i] * a[k][j];
      worst = std::max(worst, std::abs(dot - (i == j ? 1.0 : 0.0)));
    }
  const double det = a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1]) -
                     a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0]) +
                     a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
  if (worst > kRigidTolerance || det < 0)
    throw InputError(file, field,
                     "not a rigid transform (rotation part not orthonormal with det +1: max |R^T R - I| = " +
                         std::to_string(worst) + ", det = " + std::to_string(det) + ")");
  Pose34 pose;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) pose[static_cast<size_t>(r * 4 + c)] = static_cast<float>(a[r][c]);
  return pose;
}

// Resolves a frame's file path inside the dataset root; refuses paths that leave it.
std::string resolve_image(const std::string& root, const std::string& rel, const std::string& file,
                          const std::string& field, bool add_png) {
  if (rel.empty()) throw InputError(file, field, "empty path");
  fs::path p = fs::path(root) / rel;
  if (add_png && !p.has_extension()) p += ".png";
  if (add_png && p.extension() != ".png" && !fs::exists(p)) p += ".png";
  std::error_code ec;
  const fs::path canon_root = fs::weakly_canonical(fs::path(root), ec);
  const fs::path canon = fs::weakly_canonical(p, ec);
  const std::string r = canon_root.string(), c = canon.string();
  if (c.compare(0, r.size(), r) != 0 || (c.size() > r.size() && c[r.size()] != '/'))
    throw InputError(file, field, "path '" + rel + "' points outside the dataset folder");
  if (!fs::is_regular_file(canon)) throw InputError(file, field, "image not found: " + p.string());
  return canon.string();
}

std::vector<FrameJson> parse_frames(const json& j, const std::string& root, const std::string& file,
                                    bool add_png) {
  if (!j.contains("frames")) throw InputError(file, "frames", "missing");
  const json& frames = j.at("frames");
  if (!frames.is_array()) throw InputError(file, "frames", "expected an array");
  if (frames.empty()) throw InputError(file, "frames", "no frames");
  std::vector<FrameJson> out;
  for (size_t i = 0; i < frames.size(); ++i) {
    const std::string where = "frames[" + std::to_string(i) + "]";
    const json& fr = frames[i];
    if (!fr.is_object()) throw InputError(file, where, "expected an object");
    if (!fr.contains("file_path") || !fr.at("file_path").is_string())
      throw InputError(file, where + ".file_path", "missing or not a string");
    if (!fr.contains("transform_matrix")) throw InputError(file, where + ".transform_matrix", "missing");
    for (const char* k : {"fl_x", "fl_y", "cx", "cy", "w", "h", "k1", "k2", "p1", "p2"})
      if (fr.contains(k)) throw InputError(file, where + "." + k, "per-frame intrinsics are not supported");
    FrameJson f;
    f.field = where + ".file_path";
    f.image = resolve_image(root, fr.at("file_path").get<std::string>(), file, f.field, add_png);
    f.pose = parse_pose(fr.at("transform_matrix"), file, where + ".transform_matrix");
    if (fr.contains("depth_file_path")) {
      if (!fr.at("depth_file_path").is_string())
        throw InputError(file, where + ".depth_file_path", "expected a string");
      f.depth = resolve_image(root, fr.at("depth_file_path").get<std::string>(), file,
                              where + ".depth_file_path", false);
    }
    out.push_back(std::move(f));
  }
  return out;
}

bool wanted(const std::vector<std::string>& splits, const std::string& s) {
  return splits.empty() || std::find(splits.begin(), splits.end(), s) != splits.end();
}

// Blender: one json per split sharing camera_angle_x; the image size comes from the first PNG.
void read_blender(const std::string& root, const std::vector<std::string>& splits, int downscale,
                  DatasetJson& out) {
  out.format = "blender";
  double angle = -1;
  std::string first_file;
  for (const char* name : {"train", "val", "test"}) {
    const std::string file = (fs::path(root) / ("transforms_" + std::string(name) + ".json")).string();
    if (!fs::exists(file) || !wanted(splits, name)) continue;
    const json j = parse_json_file(file);
    if (!j.is_object()) throw InputError(file, "", "expected a JSON object");
    const double a = angle_field(j, file);
    if (angle < 0) {
      angle = a;
      first_file = file;
    } else if (std::abs(a - angle) > 1e-9) {
      throw InputError(file, "camera_angle_x", "differs from " + first_file + " (splits must share one camera)");
    }
    out.splits.push_back({name, file, parse_frames(j, root, file, true)});
  }
  if (out.splits.empty()) throw InputError(root, "transforms_*.json", "no split selected or present");
  const auto hw = png_size(out.splits.front().frames.front().image);
  out.height = hw.first;
  out.width = hw.second;
  const int64_t ws = out.width / downscale;
  out.fx = out.fy = 0.5 * static_cast<double>(ws) / std::tan(0.5 * angle);
}

// Frames held out as the test split of a single transforms.json: every 8th (the mip-NeRF 360 /
// LLFF convention).
constexpr size_t kTestEvery = 8;

// instant-ngp / nerfstudio: one transforms.json with shared pinhole intrinsics.
void read_transforms(const std::string& root, const std::vector<std::string>& splits, int downscale,
                     DatasetJson& out) {
  const std::string file = (fs::path(root) / "transforms.json").string();
  if (!fs::exists(file))
    throw InputError(root, "transforms_train.json", "no transforms_{train,val,test}.json or transforms.json");
  out.format = "transforms";
  const json j = parse_json_file(file);
  if (!j.is_object()) throw InputError(file, "", "expected a JSON object");
  for (const char* k : {"k1", "k2", "k3", "k4", "p1", "p2"})
    if (j.contains(k) && j.at(k).is_number() && j.at(k).get<double>() != 0.0)
      throw InputError(file, k, "lens distortion is not supported (undistort the images first)");
  if (j.contains("camera_model") && j.at("camera_model").is_string() &&
      j.at("camera_model").get<std::string>() != "OPENCV" && j.at("camera_model").get<std::string>() != "PINHOLE")
    throw InputError(file, "camera_model", "only PINHOLE (or OPENCV without distortion) is supported");
  auto frames = parse_frames(j, root, file, false);
  out.width = size_field(j, "w", file);
  out.height = size_field(j, "h", file);
  const double s = 1.0 / downscale;
  if (j.contains("fl_x")) {
    out.fx = number_field(j, "fl_x", file, "") * s;
    out.fy = j.contains("fl_y") ? number_field(j, "fl_y", file, "") * s : out.fx;
  } else if (j.contains("camera_angle_x")) {
    out.fx = out.fy = 0.5 * (out.width * s) / std::tan(0.5 * angle_field(j, file));
  } else {
    throw InputError(file, "fl_x", "missing (nor camera_angle_x)");
  }
  out.cx = j.contains("cx") ? number_field(j, "cx", file, "") * s : -1;
  out.cy = j.contains("cy") ? number_field(j, "cy", file, "") * s : -1;
  SplitJson train{"train", file, {}}, test{"test", file, {}};
  for (size_t i = 0; i < frames.size(); ++i)
    (i % kTestEvery == 0 && frames.size() > 1 ? test : train).frames.push_back(frames[i]);
  if (wanted(splits, "train") && !train.frames.empty()) out.splits.push_back(std::move(train));
  if (wanted(splits, "test") && !test.frames.empty()) out.splits.push_back(std::move(test));
}

}  // namespace

DatasetJson read_dataset_json(const std::string& root, const std::vector<std::string>& splits, int downscale) {
  if (!fs::is_directory(root)) throw InputError(root, "", "dataset folder not found");
  if (downscale < 1) throw InputError(root, "downscale", "must be >= 1");
  DatasetJson out;
  const bool blender = fs::exists(fs::path(root) / "transforms_train.json") ||
                       fs::exists(fs::path(root) / "transforms_test.json");
  if (blender) read_blender(root, splits, downscale, out);
  else read_transforms(root, splits, downscale, out);
  check_focal(out.fx, root, "focal");
  check_focal(out.fy, root, "focal");
  return out;
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
  if (j.contains("fl_x")) fx = number_field(j, "fl_x", path, "");
  else fx = 0.5 * w / std::tan(0.5 * angle_field(j, path));
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
