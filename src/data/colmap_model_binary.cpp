// COLMAP's binary model files (cameras.bin, images.bin, points3D.bin): little-endian records read
// with every length and count checked against the bytes left (colmap_model.h).
#include <cmath>
#include <cstring>
#include <string>
#include <unordered_set>
#include <vector>

#include "data/colmap_model.h"
#include "data/colmap_model_internal.h"
#include "util/errors.h"

namespace ablenerf {

using namespace colmap_detail;

namespace {

// The fewest bytes one record of each binary file can take: record counts are checked against
// these before anything is reserved, so a count the file cannot hold fails before allocating.
constexpr size_t kCameraMinBytes = 4 + 4 + 8 + 8 + kFewestParams * 8;  // id, model, width, height, params
constexpr size_t kImageMinBytes = 4 + 4 * 8 + 3 * 8 + 4 + 2 + 8;       // id, q, t, camera, "x\0", num_points2D
constexpr size_t kPoint2DBytes = 8 + 8 + 8;                            // x, y, point3D_id
constexpr size_t kPointMinBytes = 8 + 3 * 8 + 3 + 8 + 8;               // id, xyz, rgb, error, track_length
constexpr size_t kTrackEntryBytes = 4 + 4;                             // image_id, point2D_idx

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

}  // namespace

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

}  // namespace ablenerf
