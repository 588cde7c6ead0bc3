#include "data/dataset.h"

#include <unistd.h>

#include <cctype>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "util/errors.h"
#include "util/fs.h"
#include "util/image_io.h"

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
  const std::string text = mark_nonfinite(read_text_file(path));
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

// Pose (3,4 or 4,4 rows) -> (3,4) float tensor, checked finite and rigid.
torch::Tensor parse_pose(const json& m, const std::string& file, const std::string& field) {
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
    if (d > 1e-4) throw InputError(file, field, "last row must be [0, 0, 0, 1]");
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
  if (worst > 1e-3 || det < 0)
    throw InputError(file, field,
                     "not a rigid transform (rotation part not orthonormal with det +1: max |R^T R - I| = " +
                         std::to_string(worst) + ", det = " + std::to_string(det) + ")");
  auto t = torch::empty({3, 4}, torch::kFloat);
  auto acc = t.accessor<float, 2>();
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) acc[r][c] = static_cast<float>(a[r][c]);
  return t;
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

int64_t available_memory_bytes() {
  std::ifstream in("/proc/meminfo");
  std::string key;
  int64_t kb = 0;
  std::string unit;
  while (in >> key >> kb >> unit)
    if (key == "MemAvailable:") return kb * 1024;
  const long pages = sysconf(_SC_AVPHYS_PAGES), page = sysconf(_SC_PAGESIZE);
  return static_cast<int64_t>(pages) * page;
}

struct FrameSpec {
  std::string image, depth, field;
  torch::Tensor pose;
};

struct SplitSpec {
  std::string name, file;
  std::vector<FrameSpec> frames;
};

// Decodes the frames of a split into tensors.
Split decode_split(const SplitSpec& spec, const LoadOptions& opts, int expect_h, int expect_w) {
  Split s;
  s.name = spec.name;
  const int64_t n = static_cast<int64_t>(spec.frames.size());
  const int f = opts.downscale;
  const int64_t h = expect_h / f, w = expect_w / f;
  s.images = torch::empty({n, h, w, 3}, torch::kFloat);
  s.alpha = torch::empty({n, h, w}, torch::kFloat);
  std::vector<torch::Tensor> poses, depths;
  for (int64_t i = 0; i < n; ++i) {
    const auto& fr = spec.frames[static_cast<size_t>(i)];
    torch::Tensor raw = read_png(fr.image);
    if (raw.size(0) != expect_h || raw.size(1) != expect_w)
      throw InputError(fr.image, fr.field,
                       "image is " + std::to_string(raw.size(1)) + "x" + std::to_string(raw.size(0)) +
                           " but the split's images are " + std::to_string(expect_w) + "x" +
                           std::to_string(expect_h));
    torch::Tensor im = raw.to(torch::kFloat).div_(255.0f);
    if (im.size(2) == 1) im = im.expand({-1, -1, 3});
    if (im.size(2) == 3) im = torch::cat({im, torch::ones_like(im.slice(2, 0, 1))}, 2);
    im = box_downscale(im, f);  // straight RGBA, before compositing (spec 1.1)
    auto rgb = im.slice(2, 0, 3), a = im.slice(2, 3, 4);
    const float bg = opts.white_background ? 1.0f : 0.0f;
    s.images[i].copy_(rgb * a + bg * (1.0f - a));
    s.alpha[i].copy_(a.squeeze(-1));
    poses.push_back(fr.pose);
    s.files.push_back(fr.image);
    if (!fr.depth.empty()) {
      torch::Tensor d;
      try {
        const std::string bytes = read_text_file(fr.depth);
        d = torch::pickle_load(std::vector<char>(bytes.begin(), bytes.end())).toTensor().to(torch::kFloat);
      } catch (const InputError&) {
        throw;
      } catch (const std::exception&) {
        throw InputError(fr.depth, fr.field, "cannot read depth tensor");
      }
      if (d.dim() != 2 || d.size(0) != expect_h || d.size(1) != expect_w)
        throw InputError(fr.depth, fr.field, "depth map size does not match the image");
      if (f > 1) d = box_downscale(d.unsqueeze(-1), f).squeeze(-1);
      depths.push_back(d);
    }
  }
  s.c2w = torch::stack(poses);
  if (!depths.empty() && depths.size() == static_cast<size_t>(n)) s.depth = torch::stack(depths);
  return s;
}

std::vector<FrameSpec> parse_frames(const json& j, const std::string& root, const std::string& file,
                                    bool add_png) {
  if (!j.contains("frames")) throw InputError(file, "frames", "missing");
  const json& frames = j.at("frames");
  if (!frames.is_array()) throw InputError(file, "frames", "expected an array");
  if (frames.empty()) throw InputError(file, "frames", "no frames");
  std::vector<FrameSpec> out;
  for (size_t i = 0; i < frames.size(); ++i) {
    const std::string where = "frames[" + std::to_string(i) + "]";
    const json& fr = frames[i];
    if (!fr.is_object()) throw InputError(file, where, "expected an object");
    if (!fr.contains("file_path") || !fr.at("file_path").is_string())
      throw InputError(file, where + ".file_path", "missing or not a string");
    if (!fr.contains("transform_matrix")) throw InputError(file, where + ".transform_matrix", "missing");
    for (const char* k : {"fl_x", "fl_y", "cx", "cy", "w", "h", "k1", "k2", "p1", "p2"})
      if (fr.contains(k)) throw InputError(file, where + "." + k, "per-frame intrinsics are not supported");
    FrameSpec fs_;
    fs_.field = where + ".file_path";
    fs_.image = resolve_image(root, fr.at("file_path").get<std::string>(), file, fs_.field, add_png);
    fs_.pose = parse_pose(fr.at("transform_matrix"), file, where + ".transform_matrix");
    if (fr.contains("depth_file_path")) {
      if (!fr.at("depth_file_path").is_string())
        throw InputError(file, where + ".depth_file_path", "expected a string");
      fs_.depth = resolve_image(root, fr.at("depth_file_path").get<std::string>(), file,
                                where + ".depth_file_path", false);
    }
    out.push_back(std::move(fs_));
  }
  return out;
}

void check_memory(const std::vector<SplitSpec>& specs, int h, int w, const LoadOptions& opts,
                  const std::string& root) {
  int64_t frames = 0;
  for (const auto& s : specs) frames += static_cast<int64_t>(s.frames.size());
  const int64_t hh = h / opts.downscale, ww = w / opts.downscale;
  // In double: json sizes and frame counts are untrusted and their product may not fit int64.
  const double need = static_cast<double>(frames) * hh * ww * 4 * sizeof(float) +
                      static_cast<double>(h) * w * 4 * 4 * 2;  // decoded + one full-res scratch
  const int64_t have = opts.memory_limit_bytes > 0 ? opts.memory_limit_bytes : available_memory_bytes();
  if (need > static_cast<double>(have))
    throw InputError(root, "images",
                     "the decoded images need " + std::to_string(static_cast<int64_t>(need / (1 << 20))) +
                         " MiB but only " +
                         std::to_string(have / (1 << 20)) +
                         " MiB are available (try --set data.downscale=2 or fewer splits)");
}

bool wanted(const LoadOptions& o, const std::string& s) {
  return o.splits.empty() || std::find(o.splits.begin(), o.splits.end(), s) != o.splits.end();
}

}  // namespace

const Split& Dataset::split(const std::string& name) const {
  auto it = splits.find(name);
  if (it == splits.end()) throw InputError(root, "split", "the dataset has no '" + name + "' split");
  return it->second;
}

std::vector<std::string> available_splits(const std::string& root) {
  std::vector<std::string> out;
  for (const char* s : {"train", "val", "test"})
    if (fs::exists(fs::path(root) / ("transforms_" + std::string(s) + ".json"))) out.push_back(s);
  if (out.empty() && fs::exists(fs::path(root) / "transforms.json")) out = {"train", "test"};
  return out;
}

Dataset Dataset::load(const std::string& root, const LoadOptions& opts) {
  if (!fs::is_directory(root)) throw InputError(root, "", "dataset folder not found");
  if (opts.downscale < 1) throw InputError(root, "downscale", "must be >= 1");
  Dataset ds;
  ds.root = root;
  ds.near = opts.near;
  ds.far = opts.far;
  std::vector<SplitSpec> specs;
  int h = 0, w = 0;
  double fx = 0, fy = 0, cx = -1, cy = -1;

  const bool blender = fs::exists(fs::path(root) / "transforms_train.json") ||
                       fs::exists(fs::path(root) / "transforms_test.json");
  if (blender) {
    ds.format = "blender";
    double angle = -1;
    std::string first_file;
    for (const char* name : {"train", "val", "test"}) {
      const std::string file = (fs::path(root) / ("transforms_" + std::string(name) + ".json")).string();
      if (!fs::exists(file) || !wanted(opts, name)) continue;
      const json j = parse_json_file(file);
      if (!j.is_object()) throw InputError(file, "", "expected a JSON object");
      const double a = number_field(j, "camera_angle_x", file, "");
      if (a <= 0 || a >= M_PI) throw InputError(file, "camera_angle_x", "must be in (0, pi)");
      if (angle < 0) {
        angle = a;
        first_file = file;
      } else if (std::abs(a - angle) > 1e-9) {
        throw InputError(file, "camera_angle_x", "differs from " + first_file + " (splits must share one camera)");
      }
      specs.push_back({name, file, parse_frames(j, root, file, true)});
    }
    if (specs.empty()) throw InputError(root, "transforms_*.json", "no split selected or present");
    const auto hw = png_size(specs.front().frames.front().image);
    h = hw.first;
    w = hw.second;
    const int64_t ws = w / opts.downscale;
    fx = fy = 0.5 * static_cast<double>(ws) / std::tan(0.5 * angle);
  } else {
    const std::string file = (fs::path(root) / "transforms.json").string();
    if (!fs::exists(file))
      throw InputError(root, "transforms_train.json", "no transforms_{train,val,test}.json or transforms.json");
    ds.format = "transforms";
    const json j = parse_json_file(file);
    if (!j.is_object()) throw InputError(file, "", "expected a JSON object");
    for (const char* k : {"k1", "k2", "k3", "k4", "p1", "p2"})
      if (j.contains(k) && j.at(k).is_number() && j.at(k).get<double>() != 0.0)
        throw InputError(file, k, "lens distortion is not supported (undistort the images first)");
    if (j.contains("camera_model") && j.at("camera_model").is_string() &&
        j.at("camera_model").get<std::string>() != "OPENCV" && j.at("camera_model").get<std::string>() != "PINHOLE")
      throw InputError(file, "camera_model", "only PINHOLE (or OPENCV without distortion) is supported");
    auto frames = parse_frames(j, root, file, false);
    w = size_field(j, "w", file);
    h = size_field(j, "h", file);
    const double s = 1.0 / opts.downscale;
    if (j.contains("fl_x")) {
      fx = number_field(j, "fl_x", file, "") * s;
      fy = j.contains("fl_y") ? number_field(j, "fl_y", file, "") * s : fx;
    } else if (j.contains("camera_angle_x")) {
      fx = fy = 0.5 * (w * s) / std::tan(0.5 * number_field(j, "camera_angle_x", file, ""));
    } else {
      throw InputError(file, "fl_x", "missing (nor camera_angle_x)");
    }
    cx = j.contains("cx") ? number_field(j, "cx", file, "") * s : -1;
    cy = j.contains("cy") ? number_field(j, "cy", file, "") * s : -1;
    // Every 8th frame is held out as the test split (the mip-NeRF 360 / LLFF convention).
    SplitSpec train{"train", file, {}}, test{"test", file, {}};
    for (size_t i = 0; i < frames.size(); ++i) (i % 8 == 0 && frames.size() > 1 ? test : train).frames.push_back(frames[i]);
    if (wanted(opts, "train") && !train.frames.empty()) specs.push_back(train);
    if (wanted(opts, "test") && !test.frames.empty()) specs.push_back(test);
  }
  if (fx <= 0 || fy <= 0) throw InputError(root, "focal", "must be positive");
  check_memory(specs, h, w, opts, root);
  ds.intrinsics.width = w / opts.downscale;
  ds.intrinsics.height = h / opts.downscale;
  ds.intrinsics.fx = fx;
  ds.intrinsics.fy = fy;
  ds.intrinsics.cx = cx >= 0 ? cx : 0.5 * ds.intrinsics.width;
  ds.intrinsics.cy = cy >= 0 ? cy : 0.5 * ds.intrinsics.height;
  if (ds.intrinsics.width < 1 || ds.intrinsics.height < 1)
    throw InputError(root, "downscale", "larger than the images");
  for (const auto& spec : specs) ds.splits[spec.name] = decode_split(spec, opts, h, w);
  return ds;
}

CameraList load_cameras(const std::string& path, int width, int height) {
  const json j = parse_json_file(path);
  if (!j.is_object()) throw InputError(path, "", "expected a JSON object");
  if (!j.contains("frames") || !j.at("frames").is_array() || j.at("frames").empty())
    throw InputError(path, "frames", "missing or empty");
  CameraList cl;
  int w = j.contains("w") ? size_field(j, "w", path) : width;
  int h = j.contains("h") ? size_field(j, "h", path) : height;
  if (w <= 0 || h <= 0) throw InputError(path, "w", "image size unknown: give --width/--height or w/h");
  double fx;
  if (j.contains("fl_x")) fx = number_field(j, "fl_x", path, "");
  else fx = 0.5 * w / std::tan(0.5 * number_field(j, "camera_angle_x", path, ""));
  double fy = j.contains("fl_y") ? number_field(j, "fl_y", path, "") : fx;
  double cx = j.contains("cx") ? number_field(j, "cx", path, "") : 0.5 * w;
  double cy = j.contains("cy") ? number_field(j, "cy", path, "") : 0.5 * h;
  const double sx = width > 0 ? static_cast<double>(width) / w : 1.0;
  const double sy = height > 0 ? static_cast<double>(height) / h : sx;
  cl.intrinsics = {fx * sx, fy * sy, cx * sx, cy * sy, width > 0 ? width : w, height > 0 ? height : static_cast<int>(h * sy)};
  std::vector<torch::Tensor> poses;
  const json& frames = j.at("frames");
  for (size_t i = 0; i < frames.size(); ++i) {
    const std::string where = "frames[" + std::to_string(i) + "].transform_matrix";
    if (!frames[i].is_object() || !frames[i].contains("transform_matrix")) throw InputError(path, where, "missing");
    poses.push_back(parse_pose(frames[i].at("transform_matrix"), path, where));
  }
  cl.c2w = torch::stack(poses);
  return cl;
}

}  // namespace ablenerf
