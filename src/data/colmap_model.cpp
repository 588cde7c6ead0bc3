#include "data/colmap_model.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <string_view>
#include <system_error>
#include <unordered_set>

#include "util/errors.h"
#include "util/fs.h"

namespace fs = std::filesystem;

namespace ablenerf {

namespace {

// Longest excerpt of an input's text quoted in an error message.
constexpr size_t kColmapQuoteChars = 80;

// COLMAP's camera models, indexed by the model id its binary files store, with their parameter
// counts (the numbering of COLMAP's documentation; it has not changed since the format appeared).
struct CameraModelInfo {
  const char* name;
  int params;
};
constexpr CameraModelInfo kCameraModels[] = {
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
constexpr int kNumCameraModels = static_cast<int>(sizeof(kCameraModels) / sizeof(kCameraModels[0]));
constexpr size_t kFewestParams = 3;  // SIMPLE_PINHOLE

constexpr uint64_t kMaxSide = uint64_t{1} << 20;
// A 2D point without a 3D point: -1 as an int64 in both encodings.
constexpr uint64_t kNoPoint = std::numeric_limits<uint64_t>::max();
// Below this length a quaternion's direction is noise, not a rotation.
constexpr double kMinQuatNorm = 1e-6;

// The fewest bytes one record of each binary file can take: record counts are checked against
// these before anything is reserved, so a count the file cannot hold fails before allocating.
constexpr size_t kCameraMinBytes = 4 + 4 + 8 + 8 + kFewestParams * 8;  // id, model, width, height, params
constexpr size_t kImageMinBytes = 4 + 4 * 8 + 3 * 8 + 4 + 2 + 8;       // id, q, t, camera, "x\0", num_points2D
constexpr size_t kPoint2DBytes = 8 + 8 + 8;                            // x, y, point3D_id
constexpr size_t kPointMinBytes = 8 + 3 * 8 + 3 + 8 + 8;               // id, xyz, rgb, error, track_length
constexpr size_t kTrackEntryBytes = 4 + 4;                             // image_id, point2D_idx

std::string image_label(uint32_t id, const std::string& name) {
  return "image " + std::to_string(id) + " (" + printable(name, kColmapQuoteChars) + ")";
}

std::string base_name(const std::string& path) { return fs::path(path).filename().string(); }

// Little-endian reads from a whole binary file, each checked against the bytes left. The record
// being read (kind, index, id once known, name once known) is kept so that a refusal can say
// which one; the label is only composed when an error is thrown, so reading stays cheap.
class ByteReader {
 public:
  ByteReader(const std::string& bytes, const std::string& origin) : b_(bytes), origin_(origin) {}

  size_t left() const { return b_.size() - pos_; }

  // Starts record `index` (0-based) of kind "camera" / "image" / "point".
  void record(const char* kind, uint64_t index) {
    kind_ = kind;
    index_ = index;
    has_id_ = false;
    name_.clear();
    has_name_ = false;
  }
  void identify(uint64_t id) {
    id_ = id;
    has_id_ = true;
  }
  void name(const std::string& name) {
    name_ = name;
    has_name_ = true;
  }
  // "camera 3", "image 12 (IMG_0012.JPG)", "point record 5" while the id is not read yet, "" before
  // the first record.
  std::string label() const {
    if (!kind_) return "";
    std::string s =
        std::string(kind_) + (has_id_ ? " " + std::to_string(id_) : " record " + std::to_string(index_ + 1));
    if (has_name_) s += " (" + printable(name_, kColmapQuoteChars) + ")";
    return s;
  }

  uint64_t uint(size_t n, const char* what) {
    need(n, what);
    uint64_t v = 0;
    for (size_t i = 0; i < n; ++i) v |= uint64_t{static_cast<unsigned char>(b_[pos_ + i])} << (8 * i);
    pos_ += n;
    return v;
  }
  uint8_t u8(const char* what) { return static_cast<uint8_t>(uint(1, what)); }
  uint32_t u32(const char* what) { return static_cast<uint32_t>(uint(4, what)); }
  uint64_t u64(const char* what) { return uint(8, what); }
  int32_t i32(const char* what) {
    const uint32_t u = u32(what);
    int32_t v;
    std::memcpy(&v, &u, sizeof v);
    return v;
  }
  double f64(const char* what) {
    const uint64_t bits = u64(what);
    double d;
    std::memcpy(&d, &bits, sizeof d);
    return d;
  }
  // Bytes up to a '\0', which is consumed.
  std::string cstring(const char* what) {
    const size_t end = b_.find('\0', pos_);
    if (end == std::string::npos)
      throw InputError(origin_, "byte " + std::to_string(pos_),
                       "truncated: " + in_record(what) + " has no terminating NUL byte");
    std::string s = b_.substr(pos_, end - pos_);
    pos_ = end + 1;
    return s;
  }
  void skip(uint64_t n, const char* what) {
    need(n, what);
    pos_ += static_cast<size_t>(n);
  }
  // A record count (uint64) that must fit in the bytes left, each record taking at least
  // `min_bytes`. `name` is the count's field (within the current record), `items` what it counts.
  uint64_t count(size_t min_bytes, const char* name, const char* items) {
    const size_t at = pos_;
    const uint64_t n = u64(name);
    if (n > left() / min_bytes)
      throw InputError(origin_, in_record(name),
                       "claims " + std::to_string(n) + " " + items + " but only " + std::to_string(left()) +
                           " bytes follow byte " + std::to_string(at + 8) + " (each needs at least " +
                           std::to_string(min_bytes) + ")");
    return n;
  }
  void expect_end(const char* after) {
    if (pos_ != b_.size())
      throw InputError(origin_, "byte " + std::to_string(pos_),
                       std::to_string(left()) + " trailing bytes after the last of the " + after);
  }

 private:
  std::string in_record(const char* what) const { return kind_ ? label() + ": " + what : std::string(what); }
  void need(uint64_t n, const char* what) {
    if (n > left())
      throw InputError(origin_, "byte " + std::to_string(pos_),
                       "truncated: " + in_record(what) + " needs " + std::to_string(n) + " bytes, " +
                           std::to_string(left()) + " left");
  }

  const std::string& b_;
  const std::string& origin_;
  size_t pos_ = 0;
  const char* kind_ = nullptr;
  uint64_t index_ = 0, id_ = 0;
  bool has_id_ = false, has_name_ = false;
  std::string name_;
};

// The checks shared by both encodings. `where` names the record ("camera 3", "line 5: camera 3").
void check_camera(const ColmapCamera& c, const std::string& origin, const std::string& where) {
  if (c.width < 1 || c.width > kMaxSide)
    throw InputError(origin, where + ": width", std::to_string(c.width) + " is not in [1, 1048576]");
  if (c.height < 1 || c.height > kMaxSide)
    throw InputError(origin, where + ": height", std::to_string(c.height) + " is not in [1, 1048576]");
  for (size_t k = 0; k < c.params.size(); ++k)
    if (!std::isfinite(c.params[k]))
      throw InputError(origin, where + ": params[" + std::to_string(k) + "]", "non-finite value");
}

// Checks the pose and name and scales qvec to unit length.
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

// --- text files ---

struct TextLine {
  size_t number;  // 1-based
  std::string_view text;
};

bool is_space(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f'; }

bool is_blank(std::string_view s) { return std::all_of(s.begin(), s.end(), is_space); }

// The lines of a COLMAP text file without the comments (first non-blank character '#'). Blank
// lines are kept: in images.txt an image without observations has an empty second line.
std::vector<TextLine> text_lines(const std::string& text) {
  std::vector<TextLine> out;
  size_t start = 0, number = 1;
  while (start < text.size()) {
    size_t end = text.find('\n', start);
    if (end == std::string::npos) end = text.size();
    std::string_view line(text.data() + start, end - start);
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    const auto first = std::find_if_not(line.begin(), line.end(), is_space);
    if (first == line.end() || *first != '#') out.push_back({number, line});
    start = end + 1;
    ++number;
  }
  return out;
}

std::vector<std::string_view> split_fields(std::string_view line) {
  std::vector<std::string_view> out;
  size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && is_space(line[i])) ++i;
    const size_t begin = i;
    while (i < line.size() && !is_space(line[i])) ++i;
    if (i > begin) out.push_back(line.substr(begin, i - begin));
  }
  return out;
}

std::string line_label(const TextLine& l) { return "line " + std::to_string(l.number); }

// A decimal number (locale-independent). Non-finite values ("nan", "inf", 1e999) are refused
// unless `any` is set.
double parse_real(std::string_view tok, const std::string& origin, const std::string& field, bool any = false) {
  std::string_view t = tok;
  if (t.size() > 1 && t[0] == '+' && t[1] != '-') t.remove_prefix(1);
  double v = 0;
  const auto [end, ec] = std::from_chars(t.data(), t.data() + t.size(), v);
  if (end != t.data() + t.size() || (ec != std::errc() && ec != std::errc::result_out_of_range))
    throw InputError(origin, field, "expected a number, got '" + printable(tok, kColmapQuoteChars) + "'");
  if (ec == std::errc::result_out_of_range) {
    // from_chars leaves v alone when the literal is out of range; an underflow is a zero.
    if (any) return std::numeric_limits<double>::quiet_NaN();
    throw InputError(origin, field, "'" + printable(tok, kColmapQuoteChars) + "' is out of range of a double");
  }
  if (!any && !std::isfinite(v))
    throw InputError(origin, field, "non-finite value '" + printable(tok, kColmapQuoteChars) + "'");
  return v;
}

// A whole number in [0, max].
uint64_t parse_whole(std::string_view tok, uint64_t max, const std::string& origin, const std::string& field) {
  uint64_t v = 0;
  const auto [end, ec] = std::from_chars(tok.data(), tok.data() + tok.size(), v);
  if (end != tok.data() + tok.size() || (ec != std::errc() && ec != std::errc::result_out_of_range))
    throw InputError(origin, field, "expected a whole number, got '" + printable(tok, kColmapQuoteChars) + "'");
  if (ec == std::errc::result_out_of_range || v > max)
    throw InputError(origin, field,
                     "'" + printable(tok, kColmapQuoteChars) + "' is out of range [0, " + std::to_string(max) + "]");
  return v;
}

constexpr uint64_t kMaxU32 = std::numeric_limits<uint32_t>::max();
constexpr uint64_t kMaxU64 = std::numeric_limits<uint64_t>::max();

}  // namespace

const char* colmap_model_name(int model_id) {
  return model_id >= 0 && model_id < kNumCameraModels ? kCameraModels[model_id].name : "";
}

int colmap_model_params(const std::string& model) {
  for (const auto& m : kCameraModels)
    if (model == m.name) return m.params;
  return -1;
}

// --- binary files ---

std::vector<ColmapCamera> parse_cameras_bin(const std::string& bytes, const std::string& origin) {
  ByteReader r(bytes, origin);
  const uint64_t n = r.count(kCameraMinBytes, "num_cameras", "cameras");
  std::vector<ColmapCamera> out;
  out.reserve(static_cast<size_t>(n));
  std::unordered_set<uint32_t> ids;
  for (uint64_t i = 0; i < n; ++i) {
    r.record("camera", i);
    ColmapCamera c;
    c.id = r.u32("camera_id");
    r.identify(c.id);
    const int32_t model = r.i32("model_id");
    if (model < 0 || model >= kNumCameraModels)
      throw InputError(origin, r.label() + ": model_id", "unknown COLMAP camera model " + std::to_string(model));
    c.model_id = model;
    c.model = kCameraModels[model].name;
    c.width = r.u64("width");
    c.height = r.u64("height");
    const int np = kCameraModels[model].params;
    c.params.reserve(static_cast<size_t>(np));
    for (int k = 0; k < np; ++k) c.params.push_back(r.f64("params"));
    check_camera(c, origin, r.label());
    if (!ids.insert(c.id).second) throw InputError(origin, r.label() + ": camera_id", "duplicate camera id");
    out.push_back(std::move(c));
  }
  r.expect_end("cameras");
  return out;
}

std::vector<ColmapImage> parse_images_bin(const std::string& bytes, const std::string& origin) {
  ByteReader r(bytes, origin);
  const uint64_t n = r.count(kImageMinBytes, "num_images", "images");
  std::vector<ColmapImage> out;
  out.reserve(static_cast<size_t>(n));
  std::unordered_set<uint32_t> ids;
  for (uint64_t i = 0; i < n; ++i) {
    r.record("image", i);
    ColmapImage im;
    im.id = r.u32("image_id");
    r.identify(im.id);
    for (double& q : im.qvec) q = r.f64("qvec");
    for (double& t : im.tvec) t = r.f64("tvec");
    im.camera_id = r.u32("camera_id");
    im.name = r.cstring("name");
    r.name(im.name);
    check_image(im, origin, r.label());
    if (!ids.insert(im.id).second) throw InputError(origin, r.label() + ": image_id", "duplicate image id");
    const uint64_t points = r.count(kPoint2DBytes, "num_points2D", "points2D");
    im.point3d_ids.reserve(static_cast<size_t>(points));
    for (uint64_t k = 0; k < points; ++k) {
      r.skip(16, "points2D x, y");  // the 2D positions are not needed
      const uint64_t id = r.u64("points2D point3D_id");
      if (id != kNoPoint) im.point3d_ids.push_back(id);
    }
    out.push_back(std::move(im));
  }
  r.expect_end("images");
  return out;
}

std::vector<ColmapPoint> parse_points3d_bin(const std::string& bytes, const std::string& origin) {
  ByteReader r(bytes, origin);
  const uint64_t n = r.count(kPointMinBytes, "num_points", "points");
  std::vector<ColmapPoint> out;
  out.reserve(static_cast<size_t>(n));
  std::unordered_set<uint64_t> ids;
  for (uint64_t i = 0; i < n; ++i) {
    r.record("point", i);
    ColmapPoint p;
    p.id = r.u64("point3D_id");
    r.identify(p.id);
    for (double& x : p.xyz) x = r.f64("xyz");
    for (uint8_t& c : p.rgb) c = r.u8("rgb");
    p.error = r.f64("error");
    for (const double x : p.xyz)
      if (!std::isfinite(x)) throw InputError(origin, r.label() + ": xyz", "non-finite value");
    if (!ids.insert(p.id).second) throw InputError(origin, r.label() + ": point3D_id", "duplicate point id");
    const uint64_t track = r.count(kTrackEntryBytes, "track_length", "track entries");
    r.skip(track * kTrackEntryBytes, "track");  // fits: count() checked it against the bytes left
    out.push_back(p);
  }
  r.expect_end("points");
  return out;
}

// --- text files ---

std::vector<ColmapCamera> parse_cameras_txt(const std::string& text, const std::string& origin) {
  std::vector<ColmapCamera> out;
  std::unordered_set<uint32_t> ids;
  for (const TextLine& line : text_lines(text)) {
    if (is_blank(line.text)) continue;
    const auto f = split_fields(line.text);
    const std::string at = line_label(line);
    if (f.size() < 4)
      throw InputError(origin, at,
                       "expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[], got " + std::to_string(f.size()) + " fields");
    ColmapCamera c;
    c.id = static_cast<uint32_t>(parse_whole(f[0], kMaxU32, origin, at + ": CAMERA_ID"));
    const std::string where = at + ": camera " + std::to_string(c.id);
    c.model = std::string(f[1]);
    for (int k = 0; k < kNumCameraModels; ++k)
      if (c.model == kCameraModels[k].name) c.model_id = k;
    if (c.model_id < 0)
      throw InputError(origin, where + ": model",
                       "unknown COLMAP camera model '" + printable(c.model, kColmapQuoteChars) + "'");
    c.width = parse_whole(f[2], kMaxU64, origin, where + ": width");
    c.height = parse_whole(f[3], kMaxU64, origin, where + ": height");
    const size_t np = static_cast<size_t>(kCameraModels[c.model_id].params);
    if (f.size() - 4 != np)
      throw InputError(
          origin, where + ": params",
          c.model + " has " + std::to_string(np) + " parameters, the line gives " + std::to_string(f.size() - 4));
    for (size_t k = 0; k < np; ++k)
      c.params.push_back(parse_real(f[4 + k], origin, where + ": params[" + std::to_string(k) + "]"));
    check_camera(c, origin, where);
    if (!ids.insert(c.id).second) throw InputError(origin, where + ": CAMERA_ID", "duplicate camera id");
    out.push_back(std::move(c));
  }
  return out;
}

std::vector<ColmapImage> parse_images_txt(const std::string& text, const std::string& origin) {
  std::vector<ColmapImage> out;
  std::unordered_set<uint32_t> ids;
  const std::vector<TextLine> lines = text_lines(text);
  // Two lines per image: the pose line, then its 2D points (possibly empty; missing at the very
  // end of the file counts as empty). Blank lines where a pose line is due are skipped.
  for (size_t i = 0; i < lines.size();) {
    if (is_blank(lines[i].text)) {
      ++i;
      continue;
    }
    const TextLine& pose = lines[i];
    const TextLine* points = i + 1 < lines.size() ? &lines[i + 1] : nullptr;
    i += 2;
    const auto f = split_fields(pose.text);
    const std::string at = line_label(pose);
    if (f.size() < 10)
      throw InputError(
          origin, at,
          "expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, got " + std::to_string(f.size()) + " fields");
    ColmapImage im;
    im.id = static_cast<uint32_t>(parse_whole(f[0], kMaxU32, origin, at + ": IMAGE_ID"));
    const std::string id_at = at + ": image " + std::to_string(im.id);
    for (size_t k = 0; k < 4; ++k) im.qvec[k] = parse_real(f[1 + k], origin, id_at + ": qvec");
    for (size_t k = 0; k < 3; ++k) im.tvec[k] = parse_real(f[5 + k], origin, id_at + ": tvec");
    im.camera_id = static_cast<uint32_t>(parse_whole(f[8], kMaxU32, origin, id_at + ": CAMERA_ID"));
    // The name is the rest of the line, so that a name with spaces survives.
    std::string_view name = pose.text.substr(static_cast<size_t>(f[9].data() - pose.text.data()));
    while (!name.empty() && is_space(name.back())) name.remove_suffix(1);
    im.name = std::string(name);
    const std::string where = at + ": " + image_label(im.id, im.name);
    check_image(im, origin, where);
    if (!ids.insert(im.id).second) throw InputError(origin, where + ": IMAGE_ID", "duplicate image id");
    if (points) {
      const auto p = split_fields(points->text);
      const std::string pat = line_label(*points) + ": " + image_label(im.id, im.name) + ": points2D";
      if (p.size() % 3 != 0)
        throw InputError(origin, pat, "expected X Y POINT3D_ID triples, got " + std::to_string(p.size()) + " fields");
      for (size_t k = 0; k < p.size(); k += 3) {
        parse_real(p[k], origin, pat + " X");
        parse_real(p[k + 1], origin, pat + " Y");
        if (p[k + 2] == "-1") continue;  // an observation without a 3D point
        im.point3d_ids.push_back(parse_whole(p[k + 2], kMaxU64, origin, pat + " POINT3D_ID"));
        if (im.point3d_ids.back() == kNoPoint) im.point3d_ids.pop_back();
      }
    }
    out.push_back(std::move(im));
  }
  return out;
}

std::vector<ColmapPoint> parse_points3d_txt(const std::string& text, const std::string& origin) {
  std::vector<ColmapPoint> out;
  std::unordered_set<uint64_t> ids;
  for (const TextLine& line : text_lines(text)) {
    if (is_blank(line.text)) continue;
    const auto f = split_fields(line.text);
    const std::string at = line_label(line);
    if (f.size() < 8 || (f.size() - 8) % 2 != 0)
      throw InputError(origin, at,
                       "expected POINT3D_ID X Y Z R G B ERROR and (IMAGE_ID POINT2D_IDX) pairs, got " +
                           std::to_string(f.size()) + " fields");
    ColmapPoint p;
    p.id = parse_whole(f[0], kMaxU64, origin, at + ": POINT3D_ID");
    const std::string where = at + ": point " + std::to_string(p.id);
    for (size_t k = 0; k < 3; ++k) p.xyz[k] = parse_real(f[1 + k], origin, where + ": xyz");
    for (size_t k = 0; k < 3; ++k) p.rgb[k] = static_cast<uint8_t>(parse_whole(f[4 + k], 255, origin, where + ": rgb"));
    p.error = parse_real(f[7], origin, where + ": error", /*any=*/true);
    for (size_t k = 8; k < f.size(); ++k) parse_whole(f[k], kMaxU32, origin, where + ": track");
    if (!ids.insert(p.id).second) throw InputError(origin, where + ": POINT3D_ID", "duplicate point id");
    out.push_back(p);
  }
  return out;
}

// --- the model ---

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
