#include "data/colmap_model.h"

#include <cmath>
#include <cstring>
#include <filesystem>
#include <set>
#include <sstream>

#include "util/errors.h"
#include "util/fs.h"

namespace fs = std::filesystem;

namespace ablenerf {

namespace {

struct ModelInfo {
  const char* name;
  int params;
};
// COLMAP's model ids 0..10.
const ModelInfo kModels[] = {{"SIMPLE_PINHOLE", 3}, {"PINHOLE", 4},        {"SIMPLE_RADIAL", 4},
                             {"RADIAL", 5},         {"OPENCV", 8},         {"OPENCV_FISHEYE", 8},
                             {"FULL_OPENCV", 12},   {"FOV", 5},            {"SIMPLE_RADIAL_FISHEYE", 4},
                             {"RADIAL_FISHEYE", 5}, {"THIN_PRISM_FISHEYE", 12}};
constexpr uint64_t kMaxSide = uint64_t(1) << 20;

// A little-endian reader over a byte buffer; every read checks the bytes left.
class Reader {
 public:
  Reader(const std::string& b, const std::string& origin) : b_(b), origin_(origin) {}
  template <class T>
  T get(const std::string& what) {
    if (b_.size() - pos_ < sizeof(T)) throw InputError(origin_, "byte " + std::to_string(pos_), "truncated: " + what);
    T v;
    std::memcpy(&v, b_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    return v;
  }
  double finite(const std::string& what) {
    const double d = get<double>(what);
    if (!std::isfinite(d)) throw InputError(origin_, what, "non-finite value");
    return d;
  }
  std::string cstring(const std::string& what) {
    const size_t end = b_.find('\0', pos_);
    if (end == std::string::npos) throw InputError(origin_, "byte " + std::to_string(pos_), "truncated: " + what);
    std::string s = b_.substr(pos_, end - pos_);
    pos_ = end + 1;
    return s;
  }
  // A record count, checked against the bytes left (each record needs at least `min_size`).
  uint64_t count(size_t min_size, const std::string& what) {
    const uint64_t n = get<uint64_t>(what);
    if (n > (b_.size() - pos_) / std::max<size_t>(min_size, 1))
      throw InputError(origin_, what, "count " + std::to_string(n) + " exceeds the file's size");
    return n;
  }
  void skip(uint64_t n, const std::string& what) {
    if (b_.size() - pos_ < n) throw InputError(origin_, "byte " + std::to_string(pos_), "truncated: " + what);
    pos_ += n;
  }
  void expect_end() {
    if (pos_ != b_.size()) throw InputError(origin_, "byte " + std::to_string(pos_), "trailing bytes after the last record");
  }

 private:
  const std::string& b_;
  const std::string& origin_;
  size_t pos_ = 0;
};

void check_camera(ColmapCamera& c, const std::string& origin) {
  const std::string where = "camera " + std::to_string(c.id);
  if (c.width < 1 || c.height < 1 || c.width > kMaxSide || c.height > kMaxSide)
    throw InputError(origin, where + ": size", "width and height must be in [1, 2^20]");
  for (double p : c.params)
    if (!std::isfinite(p)) throw InputError(origin, where + ": params", "non-finite value");
}

void check_image(ColmapImage& im, const std::string& origin) {
  const std::string where = "image " + std::to_string(im.id);
  double n = 0;
  for (double q : im.qvec) n += q * q;
  n = std::sqrt(n);
  if (!(n > 1e-6) || !std::isfinite(n)) throw InputError(origin, where + ": qvec", "not a rotation (zero or non-finite)");
  for (double& q : im.qvec) q /= n;
  for (double t : im.tvec)
    if (!std::isfinite(t)) throw InputError(origin, where + ": tvec", "non-finite value");
  if (im.name.empty()) throw InputError(origin, where + ": name", "empty");
}

template <class T, class Id>
void unique_ids(const std::vector<T>& v, Id id, const std::string& origin, const std::string& what) {
  std::set<uint64_t> seen;
  for (const auto& x : v)
    if (!seen.insert(id(x)).second) throw InputError(origin, what + " " + std::to_string(id(x)), "duplicate id");
}

// Non-comment, non-empty lines of a COLMAP text file (images.txt keeps empty point lines: `keep_empty`).
std::vector<std::string> data_lines(const std::string& text, bool keep_empty) {
  std::vector<std::string> out;
  std::istringstream in(text);
  std::string line;
  while (std::getline(in, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (!line.empty() && line[0] == '#') continue;
    if (line.find_first_not_of(" \t") == std::string::npos && !keep_empty) continue;
    out.push_back(line);
  }
  return out;
}

double parse_double(const std::string& tok, const std::string& origin, const std::string& where) {
  try {
    size_t used = 0;
    const double d = std::stod(tok, &used);
    if (used != tok.size() || !std::isfinite(d)) throw std::invalid_argument("");
    return d;
  } catch (const std::exception&) {
    throw InputError(origin, where, "expected a finite number, got '" + tok + "'");
  }
}

uint64_t parse_uint(const std::string& tok, const std::string& origin, const std::string& where) {
  if (tok.empty() || tok.size() > 19 || tok.find_first_not_of("0123456789") != std::string::npos)
    throw InputError(origin, where, "expected a whole number, got '" + tok + "'");
  return std::stoull(tok);
}

std::vector<std::string> tokens(const std::string& line) {
  std::istringstream in(line);
  std::vector<std::string> t;
  std::string s;
  while (in >> s) t.push_back(s);
  return t;
}

}  // namespace

const char* colmap_model_name(int id) { return id >= 0 && id < 11 ? kModels[id].name : ""; }

int colmap_model_params(const std::string& model) {
  for (const auto& m : kModels)
    if (model == m.name) return m.params;
  return -1;
}

std::vector<ColmapCamera> parse_cameras_bin(const std::string& b, const std::string& origin) {
  Reader r(b, origin);
  const uint64_t n = r.count(24, "num_cameras");
  std::vector<ColmapCamera> out;
  for (uint64_t i = 0; i < n; ++i) {
    ColmapCamera c;
    c.id = r.get<uint32_t>("camera_id");
    c.model_id = r.get<int32_t>("model_id");
    if (c.model_id < 0 || c.model_id > 10)
      throw InputError(origin, "camera " + std::to_string(c.id) + ": model_id", "unknown COLMAP camera model " + std::to_string(c.model_id));
    c.model = kModels[c.model_id].name;
    c.width = r.get<uint64_t>("width");
    c.height = r.get<uint64_t>("height");
    for (int k = 0; k < kModels[c.model_id].params; ++k) c.params.push_back(r.get<double>("params"));
    check_camera(c, origin);
    out.push_back(std::move(c));
  }
  r.expect_end();
  unique_ids(out, [](const ColmapCamera& c) { return uint64_t{c.id}; }, origin, "camera");
  return out;
}

std::vector<ColmapImage> parse_images_bin(const std::string& b, const std::string& origin) {
  Reader r(b, origin);
  const uint64_t n = r.count(4 + 7 * 8 + 4 + 1 + 8, "num_images");
  std::vector<ColmapImage> out;
  for (uint64_t i = 0; i < n; ++i) {
    ColmapImage im;
    im.id = r.get<uint32_t>("image_id");
    for (double& q : im.qvec) q = r.get<double>("qvec");
    for (double& t : im.tvec) t = r.get<double>("tvec");
    im.camera_id = r.get<uint32_t>("camera_id");
    im.name = r.cstring("name");
    const uint64_t points = r.count(24, "image " + std::to_string(im.id) + ": num_points2D");
    r.skip(points * 24, "points2D");
    check_image(im, origin);
    out.push_back(std::move(im));
  }
  r.expect_end();
  unique_ids(out, [](const ColmapImage& m) { return uint64_t{m.id}; }, origin, "image");
  return out;
}

std::vector<ColmapPoint> parse_points3d_bin(const std::string& b, const std::string& origin) {
  Reader r(b, origin);
  const uint64_t n = r.count(8 + 24 + 3 + 8 + 8, "num_points");
  std::vector<ColmapPoint> out;
  out.reserve(static_cast<size_t>(n));
  for (uint64_t i = 0; i < n; ++i) {
    ColmapPoint p;
    p.id = r.get<uint64_t>("point3D_id");
    for (double& x : p.xyz) x = r.finite("point " + std::to_string(p.id) + ": xyz");
    r.skip(3, "rgb");
    r.get<double>("error");
    const uint64_t track = r.count(8, "point " + std::to_string(p.id) + ": track_length");
    r.skip(track * 8, "track");
    out.push_back(p);
  }
  r.expect_end();
  return out;
}

std::vector<ColmapCamera> parse_cameras_txt(const std::string& text, const std::string& origin) {
  std::vector<ColmapCamera> out;
  for (const auto& line : data_lines(text, false)) {
    const auto t = tokens(line);
    const std::string where = "line '" + line.substr(0, 40) + "'";
    if (t.size() < 4) throw InputError(origin, where, "expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]");
    ColmapCamera c;
    c.id = static_cast<uint32_t>(parse_uint(t[0], origin, where));
    c.model = t[1];
    const int np = colmap_model_params(c.model);
    if (np < 0) throw InputError(origin, "camera " + t[0] + ": model", "unknown COLMAP camera model " + c.model);
    for (int k = 0; k < 11; ++k)
      if (c.model == kModels[k].name) c.model_id = k;
    c.width = parse_uint(t[2], origin, where);
    c.height = parse_uint(t[3], origin, where);
    if (static_cast<int>(t.size()) != 4 + np)
      throw InputError(origin, "camera " + t[0] + ": params", c.model + " needs " + std::to_string(np) + " parameters");
    for (int k = 0; k < np; ++k) c.params.push_back(parse_double(t[static_cast<size_t>(4 + k)], origin, where));
    check_camera(c, origin);
    out.push_back(std::move(c));
  }
  unique_ids(out, [](const ColmapCamera& c) { return uint64_t{c.id}; }, origin, "camera");
  return out;
}

std::vector<ColmapImage> parse_images_txt(const std::string& text, const std::string& origin) {
  std::vector<ColmapImage> out;
  const auto lines = data_lines(text, true);
  for (size_t i = 0; i < lines.size(); ++i) {
    const auto t = tokens(lines[i]);
    if (t.empty()) continue;  // an empty points line
    const std::string where = "line '" + lines[i].substr(0, 40) + "'";
    if (t.size() < 10) throw InputError(origin, where, "expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME");
    ColmapImage im;
    im.id = static_cast<uint32_t>(parse_uint(t[0], origin, where));
    for (int k = 0; k < 4; ++k) im.qvec[static_cast<size_t>(k)] = parse_double(t[static_cast<size_t>(1 + k)], origin, where);
    for (int k = 0; k < 3; ++k) im.tvec[static_cast<size_t>(k)] = parse_double(t[static_cast<size_t>(5 + k)], origin, where);
    im.camera_id = static_cast<uint32_t>(parse_uint(t[8], origin, where));
    // The name is the rest of the line (it may hold spaces).
    const std::string& l = lines[i];
    size_t p = 0;
    for (int k = 0; k < 9; ++k) {
      p = l.find_first_not_of(" \t", p);
      p = l.find_first_of(" \t", p);
    }
    im.name = l.substr(l.find_first_not_of(" \t", p));
    while (!im.name.empty() && (im.name.back() == ' ' || im.name.back() == '\t')) im.name.pop_back();
    check_image(im, origin);
    out.push_back(std::move(im));
    ++i;  // the points2D line that follows
  }
  unique_ids(out, [](const ColmapImage& m) { return uint64_t{m.id}; }, origin, "image");
  return out;
}

std::vector<ColmapPoint> parse_points3d_txt(const std::string& text, const std::string& origin) {
  std::vector<ColmapPoint> out;
  for (const auto& line : data_lines(text, false)) {
    const auto t = tokens(line);
    const std::string where = "line '" + line.substr(0, 40) + "'";
    if (t.size() < 8) throw InputError(origin, where, "expected POINT3D_ID X Y Z R G B ERROR TRACK[]");
    ColmapPoint p;
    p.id = parse_uint(t[0], origin, where);
    for (int k = 0; k < 3; ++k) p.xyz[static_cast<size_t>(k)] = parse_double(t[static_cast<size_t>(1 + k)], origin, where);
    out.push_back(p);
  }
  return out;
}

ColmapModel read_colmap_model(const std::string& dir) {
  ColmapModel m;
  m.dir = dir;
  const fs::path d(dir);
  m.encoding = fs::exists(d / "cameras.bin") ? "bin" : "txt";
  const auto file = [&](const char* name) { return (d / (std::string(name) + "." + m.encoding)).string(); };
  if (!fs::exists(file("cameras"))) throw InputError(dir, "cameras." + m.encoding, "missing");
  if (!fs::exists(file("images"))) throw InputError(dir, "images." + m.encoding, "missing");
  const bool bin = m.encoding == "bin";
  m.cameras = bin ? parse_cameras_bin(read_file(file("cameras")), file("cameras"))
                  : parse_cameras_txt(read_file(file("cameras")), file("cameras"));
  m.images = bin ? parse_images_bin(read_file(file("images")), file("images"))
                 : parse_images_txt(read_file(file("images")), file("images"));
  if (fs::exists(file("points3D")))
    m.points = bin ? parse_points3d_bin(read_file(file("points3D")), file("points3D"))
                   : parse_points3d_txt(read_file(file("points3D")), file("points3D"));
  std::set<uint32_t> cams;
  for (const auto& c : m.cameras) cams.insert(c.id);
  for (const auto& im : m.images)
    if (!cams.count(im.camera_id))
      throw InputError(file("images"), "image " + std::to_string(im.id) + " (" + im.name + "): camera_id",
                       "camera " + std::to_string(im.camera_id) + " is not in " + file("cameras"));
  return m;
}

}  // namespace ablenerf
