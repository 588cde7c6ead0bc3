// COLMAP model reader (data/colmap_model): a small model (2 cameras, 3 images, 4 points) written
// here byte by byte in the binary encoding and line by line in the text encoding, read back to
// exactly the values written, both encodings comparing equal; then every refusal: truncation at
// every byte, unknown model ids, counts the file cannot hold, missing cameras, duplicate ids,
// trailing bytes, wrong parameter counts, non-finite values, bad sizes, names and quaternions.
// Torch-free.
#include "data/colmap_model.h"
#include "test_util.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "util/errors.h"

using namespace ablenerf;
using namespace std::string_literals;
namespace fs = std::filesystem;

namespace {

// A fresh folder under the system temp dir, removed with its contents when the object dies.
class ScratchDir {
 public:
  ScratchDir() {
    static int counter = 0;
    path_ = (fs::temp_directory_path() /
             ("ablenerf_colmap_test_" + std::to_string(::getpid()) + "_" + std::to_string(counter++)))
                .string();
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~ScratchDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  ScratchDir(const ScratchDir&) = delete;
  ScratchDir& operator=(const ScratchDir&) = delete;
  const std::string& path() const { return path_; }
  std::string operator/(const std::string& name) const { return path_ + "/" + name; }

 private:
  std::string path_;
};

void write_text(const std::string& path, const std::string& bytes) {
  std::ofstream f(path, std::ios::binary);
  f << bytes;
  ASSERT_TRUE(f.good()) << path;
}

// Little-endian writer, one byte at a time, independent of the reader under test.
struct Bytes {
  std::string s;
  Bytes& uint(uint64_t v, int n) {
    for (int i = 0; i < n; ++i) s += static_cast<char>((v >> (8 * i)) & 0xff);
    return *this;
  }
  Bytes& u8(uint8_t v) { return uint(v, 1); }
  Bytes& u32(uint32_t v) { return uint(v, 4); }
  Bytes& i32(int32_t v) { return uint(static_cast<uint32_t>(v), 4); }
  Bytes& u64(uint64_t v) { return uint(v, 8); }
  Bytes& i64(int64_t v) { return uint(static_cast<uint64_t>(v), 8); }
  Bytes& f64(double d) {
    uint64_t bits;
    std::memcpy(&bits, &d, 8);
    return uint(bits, 8);
  }
  Bytes& raw(const std::string& t) {
    s += t;
    return *this;
  }
};

// The reference model, as the files hold it (qvec not normalised, observations with id -1).
struct Obs {
  double x, y;
  int64_t point;  // -1: none
};
struct RefCamera {
  uint32_t id;
  int model_id;
  std::string model;
  uint64_t width, height;
  std::vector<double> params;
};
struct RefImage {
  uint32_t id;
  std::array<double, 4> q;
  std::array<double, 3> t;
  uint32_t camera;
  std::string name;
  std::vector<Obs> obs;
};
struct RefPoint {
  uint64_t id;
  std::array<double, 3> xyz;
  std::array<uint8_t, 3> rgb;
  double error;
  std::vector<std::pair<uint32_t, uint32_t>> track;
};
struct RefModel {
  std::vector<RefCamera> cameras;
  std::vector<RefImage> images;
  std::vector<RefPoint> points;
};

RefModel reference() {
  RefModel m;
  m.cameras = {{1, 1, "PINHOLE", 640, 480, {500.25, 501.5, 320.1, 240.3}},
               {7, 4, "OPENCV", 1024, 768, {800, 810.5, 512.5, 383.25, -0.1, 0.01, 1e-3, -2e-4}}};
  m.images = {{3, {2, 0, 0, 0}, {0.1, -0.2, 4.5}, 1, "IMG_0003.JPG", {{10.5, 20.25, 100}, {3, 4, -1}, {5, 6, 101}}},
              {12, {1, 2, 3, 4}, {1e-3, 2, -3}, 7, "sub dir/IMG 0012.JPG", {{1, 2, -1}}},
              {5, {0.5, -0.5, 0.5, -0.5}, {0, 0, 0}, 1, "c.png", {}}};
  m.points = {{100, {0.5, -1.25, 3}, {255, 0, 17}, 0.75, {{3, 0}, {12, 0}}},
              {101, {-2, 1e-3, 7.5}, {1, 2, 3}, 0.125, {{3, 2}}},
              {102, {0, 0, 0}, {9, 9, 9}, 1.5, {}},
              {(uint64_t{1} << 40) + 5, {1e6, -1e6, 2.5}, {128, 64, 32}, 0, {{5, 0}, {3, 1}, {12, 0}}}};
  return m;
}

std::string cameras_bin(const RefModel& m) {
  Bytes b;
  b.u64(m.cameras.size());
  for (const auto& c : m.cameras) {
    b.u32(c.id).i32(c.model_id).u64(c.width).u64(c.height);
    for (double p : c.params) b.f64(p);
  }
  return b.s;
}

std::string images_bin(const RefModel& m) {
  Bytes b;
  b.u64(m.images.size());
  for (const auto& im : m.images) {
    b.u32(im.id);
    for (double q : im.q) b.f64(q);
    for (double t : im.t) b.f64(t);
    b.u32(im.camera).raw(im.name).u8(0).u64(im.obs.size());
    for (const auto& o : im.obs) b.f64(o.x).f64(o.y).i64(o.point);
  }
  return b.s;
}

std::string points_bin(const RefModel& m) {
  Bytes b;
  b.u64(m.points.size());
  for (const auto& p : m.points) {
    b.u64(p.id);
    for (double x : p.xyz) b.f64(x);
    for (uint8_t c : p.rgb) b.u8(c);
    b.f64(p.error).u64(p.track.size());
    for (const auto& e : p.track) b.u32(e.first).u32(e.second);
  }
  return b.s;
}

// Shortest text that reads back to the same double (%.17g always does).
std::string num(double v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

std::string cameras_txt(const RefModel& m) {
  std::string s = "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n";
  for (const auto& c : m.cameras) {
    s += std::to_string(c.id) + " " + c.model + " " + std::to_string(c.width) + " " + std::to_string(c.height);
    for (double p : c.params) s += " " + num(p);
    s += "\n";
  }
  return s;
}

std::string images_txt(const RefModel& m) {
  std::string s = "# Image list with two lines of data per image:\n";
  for (const auto& im : m.images) {
    s += std::to_string(im.id);
    for (double q : im.q) s += " " + num(q);
    for (double t : im.t) s += " " + num(t);
    s += " " + std::to_string(im.camera) + " " + im.name + "\n";
    for (size_t k = 0; k < im.obs.size(); ++k)
      s += (k ? " " : "") + num(im.obs[k].x) + " " + num(im.obs[k].y) + " " + std::to_string(im.obs[k].point);
    s += "\n";  // empty for an image without observations
  }
  return s;
}

std::string points_txt(const RefModel& m) {
  std::string s = "# 3D point list with one line of data per point:\n";
  for (const auto& p : m.points) {
    s += std::to_string(p.id);
    for (double x : p.xyz) s += " " + num(x);
    for (uint8_t c : p.rgb) s += " " + std::to_string(c);
    s += " " + num(p.error);
    for (const auto& e : p.track) s += " " + std::to_string(e.first) + " " + std::to_string(e.second);
    s += "\n";
  }
  return s;
}

void write_bin(const std::string& dir, const RefModel& m) {
  write_text(dir + "/cameras.bin", cameras_bin(m));
  write_text(dir + "/images.bin", images_bin(m));
  write_text(dir + "/points3D.bin", points_bin(m));
}

void write_txt(const std::string& dir, const RefModel& m) {
  write_text(dir + "/cameras.txt", cameras_txt(m));
  write_text(dir + "/images.txt", images_txt(m));
  write_text(dir + "/points3D.txt", points_txt(m));
}

// The model `ref` describes, as the reader must return it.
void expect_matches(const ColmapModel& got, const RefModel& ref) {
  ASSERT_EQ(got.cameras.size(), ref.cameras.size());
  for (size_t i = 0; i < ref.cameras.size(); ++i) {
    const auto& g = got.cameras[i];
    const auto& r = ref.cameras[i];
    EXPECT_EQ(g.id, r.id);
    EXPECT_EQ(g.model, r.model);
    EXPECT_EQ(g.model_id, r.model_id);
    EXPECT_EQ(g.width, r.width);
    EXPECT_EQ(g.height, r.height);
    EXPECT_EQ(g.params, r.params);  // exact: both encodings carry every bit
  }
  ASSERT_EQ(got.images.size(), ref.images.size());
  for (size_t i = 0; i < ref.images.size(); ++i) {
    const auto& g = got.images[i];
    const auto& r = ref.images[i];
    EXPECT_EQ(g.id, r.id);
    const double n = std::sqrt(r.q[0] * r.q[0] + r.q[1] * r.q[1] + r.q[2] * r.q[2] + r.q[3] * r.q[3]);
    for (size_t k = 0; k < 4; ++k) EXPECT_NEAR(g.qvec[k], r.q[k] / n, 1e-15) << "image " << r.id << " q" << k;
    for (size_t k = 0; k < 3; ++k) EXPECT_EQ(g.tvec[k], r.t[k]);
    EXPECT_EQ(g.camera_id, r.camera);
    EXPECT_EQ(g.name, r.name);
    std::vector<uint64_t> ids;
    for (const auto& o : r.obs)
      if (o.point != -1) ids.push_back(static_cast<uint64_t>(o.point));
    EXPECT_EQ(g.point3d_ids, ids) << "image " << r.id;
  }
  ASSERT_EQ(got.points.size(), ref.points.size());
  for (size_t i = 0; i < ref.points.size(); ++i) {
    const auto& g = got.points[i];
    const auto& r = ref.points[i];
    EXPECT_EQ(g.id, r.id);
    EXPECT_EQ(g.xyz, r.xyz);
    EXPECT_EQ(g.rgb, r.rgb);
    EXPECT_EQ(g.error, r.error);
  }
}

// Expects `f` to throw an InputError for `file` whose field holds `field` and whose message holds
// `what`, on one line.
void expect_refused(const std::function<void()>& f, const std::string& file, const std::string& field,
                    const std::string& what = "") {
  test::expect_input_error(f, file, field, what, /*exact_field=*/false);
}

}  // namespace

TEST(ColmapModel, BinaryReadsBackWhatWasWritten) {
  ScratchDir d;
  const RefModel ref = reference();
  write_bin(d.path(), ref);
  const ColmapModel m = read_colmap_model(d.path());
  EXPECT_EQ(m.encoding, "bin");
  EXPECT_EQ(m.dir, d.path());
  expect_matches(m, ref);
  // Spot checks by hand, independent of expect_matches: 1/sqrt(30) * (1, 2, 3, 4).
  EXPECT_NEAR(m.images[1].qvec[3], 4 / std::sqrt(30.0), 1e-15);
  EXPECT_EQ(m.images[0].point3d_ids, (std::vector<uint64_t>{100, 101}));
  EXPECT_TRUE(m.images[1].point3d_ids.empty());
  EXPECT_EQ(m.points[3].id, 1099511627781u);
}

TEST(ColmapModel, TextReadsBackWhatWasWrittenAndEqualsBinary) {
  ScratchDir t, b;
  const RefModel ref = reference();
  write_txt(t.path(), ref);
  write_bin(b.path(), ref);
  const ColmapModel txt = read_colmap_model(t.path());
  EXPECT_EQ(txt.encoding, "txt");
  expect_matches(txt, ref);
  const ColmapModel bin = read_colmap_model(b.path());
  ASSERT_EQ(txt.cameras.size(), bin.cameras.size());
  for (size_t i = 0; i < bin.cameras.size(); ++i) {
    EXPECT_EQ(txt.cameras[i].params, bin.cameras[i].params);
    EXPECT_EQ(txt.cameras[i].model_id, bin.cameras[i].model_id);
  }
  ASSERT_EQ(txt.images.size(), bin.images.size());
  for (size_t i = 0; i < bin.images.size(); ++i) {
    EXPECT_EQ(txt.images[i].qvec, bin.images[i].qvec);  // the same bits, the same arithmetic
    EXPECT_EQ(txt.images[i].tvec, bin.images[i].tvec);
    EXPECT_EQ(txt.images[i].name, bin.images[i].name);
    EXPECT_EQ(txt.images[i].point3d_ids, bin.images[i].point3d_ids);
  }
  ASSERT_EQ(txt.points.size(), bin.points.size());
  for (size_t i = 0; i < bin.points.size(); ++i) {
    EXPECT_EQ(txt.points[i].xyz, bin.points[i].xyz);
    EXPECT_EQ(txt.points[i].rgb, bin.points[i].rgb);
    EXPECT_EQ(txt.points[i].error, bin.points[i].error);
  }
}

TEST(ColmapModel, TextToleratesCrlfCommentsAndMissingLastPointsLine) {
  const std::string cams = "# c\r\n\r\n1 SIMPLE_PINHOLE 10 20 5 5 10\r\n  # indented comment\r\n";
  const auto c = parse_cameras_txt(cams, "cameras.txt");
  ASSERT_EQ(c.size(), 1u);
  EXPECT_EQ(c[0].params, (std::vector<double>{5, 5, 10}));
  // The last image's points line is missing altogether; a comment sits between a pose and its points.
  const std::string imgs = "1 1 0 0 0 0 0 0 1 a.png\n# between\n1 2 -1 3 4 9\n2 1 0 0 0 0 0 0 1 b.png";
  const auto im = parse_images_txt(imgs, "images.txt");
  ASSERT_EQ(im.size(), 2u);
  EXPECT_EQ(im[0].point3d_ids, (std::vector<uint64_t>{9}));
  EXPECT_EQ(im[1].name, "b.png");
}

TEST(ColmapModel, PrefersBinaryAndPointsMayBeAbsent) {
  ScratchDir d;
  RefModel ref = reference();
  write_txt(d.path(), ref);
  write_bin(d.path(), ref);
  EXPECT_EQ(read_colmap_model(d.path()).encoding, "bin");
  fs::remove(d / "points3D.bin");
  const ColmapModel m = read_colmap_model(d.path());
  EXPECT_EQ(m.encoding, "bin");
  EXPECT_TRUE(m.points.empty());
  EXPECT_EQ(m.images.size(), 3u);
  fs::remove(d / "points3D.txt");
  fs::remove(d / "cameras.bin");
  EXPECT_EQ(read_colmap_model(d.path()).encoding, "txt");
}

TEST(ColmapModel, MissingCamerasOrImages) {
  ScratchDir d;
  expect_refused([&] { read_colmap_model(d.path()); }, d.path(), "cameras.bin|cameras.txt", "missing");
  write_text(d / "cameras.bin", cameras_bin(reference()));
  expect_refused([&] { read_colmap_model(d.path()); }, d.path(), "images.bin", "missing");
  ScratchDir t;
  write_text(t / "cameras.txt", cameras_txt(reference()));
  expect_refused([&] { read_colmap_model(t.path()); }, t.path(), "images.txt", "missing");
}

TEST(ColmapModel, TruncatedAtEveryByte) {
  const RefModel ref = reference();
  const std::string files[3] = {cameras_bin(ref), images_bin(ref), points_bin(ref)};
  const char* names[3] = {"cameras.bin", "images.bin", "points3D.bin"};
  for (int f = 0; f < 3; ++f) {
    for (size_t cut = 0; cut < files[f].size(); ++cut) {
      SCOPED_TRACE(std::string(names[f]) + " cut at " + std::to_string(cut));
      const std::string part = files[f].substr(0, cut);
      expect_refused(
          [&] {
            if (f == 0) parse_cameras_bin(part, names[f]);
            if (f == 1) parse_images_bin(part, names[f]);
            if (f == 2) parse_points3d_bin(part, names[f]);
          },
          names[f], "");
    }
  }
  // A few cut points in detail: the byte where reading stopped and what was being read.
  expect_refused([&] { parse_cameras_bin(files[0].substr(0, 5), "cameras.bin"); }, "cameras.bin", "byte 0",
                 "truncated");
  expect_refused([&] { parse_cameras_bin(files[0].substr(0, 8 + 4 + 4 + 8 + 8 + 8), "cameras.bin"); }, "cameras.bin",
                 "num_cameras", "claims 2 cameras");
  expect_refused([&] { parse_cameras_bin(files[0].substr(0, files[0].size() - 3), "cameras.bin"); }, "cameras.bin",
                 "byte", "truncated: camera 7: params");
  expect_refused([&] { parse_images_bin(files[1].substr(0, files[1].size() - 1), "images.bin"); }, "images.bin", "byte",
                 "truncated: image 5 (c.png): num_points2D");
  // On disk too: read_colmap_model names the file. The last point's track is cut short, which the
  // track length, checked against the bytes left, already shows.
  ScratchDir d;
  write_bin(d.path(), ref);
  write_text(d / "points3D.bin", files[2].substr(0, files[2].size() - 2));
  expect_refused([&] { read_colmap_model(d.path()); }, d / "points3D.bin", "point 1099511627781: track_length",
                 "claims 3 track entries but only 22 bytes follow");
  write_text(d / "points3D.bin", files[2]);
  // images.bin: the count (8 bytes), image 3 (157 bytes), then image 12 whose name starts at byte
  // 8 + 157 + 4 + 32 + 24 + 4: cut inside the name.
  write_text(d / "images.bin", files[1].substr(0, 240));
  expect_refused([&] { read_colmap_model(d.path()); }, d / "images.bin", "byte 229",
                 "truncated: image 12: name has no terminating NUL byte");
}

TEST(ColmapModel, UnknownModel) {
  RefModel ref = reference();
  ref.cameras[1].id = 3;
  ref.cameras[1].model_id = 17;
  expect_refused([&] { parse_cameras_bin(cameras_bin(ref), "sparse/0/cameras.bin"); }, "sparse/0/cameras.bin",
                 "camera 3: model_id", "unknown COLMAP camera model 17");
  ref.cameras[1].model_id = -1;
  expect_refused([&] { parse_cameras_bin(cameras_bin(ref), "cameras.bin"); }, "cameras.bin", "camera 3: model_id",
                 "unknown COLMAP camera model -1");
  expect_refused([&] { parse_cameras_txt("3 PINHOLEX 10 10 1 1 1 1\n", "cameras.txt"); }, "cameras.txt",
                 "line 1: camera 3: model", "unknown COLMAP camera model 'PINHOLEX'");
}

TEST(ColmapModel, HugeCountsFailBeforeAllocating) {
  const uint64_t huge = uint64_t{1} << 60;
  expect_refused([&] { parse_cameras_bin(Bytes().u64(huge).s, "cameras.bin"); }, "cameras.bin", "num_cameras");
  expect_refused([&] { parse_images_bin(Bytes().u64(~uint64_t{0}).s, "images.bin"); }, "images.bin", "num_images");
  expect_refused([&] { parse_points3d_bin(Bytes().u64(huge).s, "points3D.bin"); }, "points3D.bin", "num_points");
  // A count inside a record: num_points2D and track_length.
  RefModel ref = reference();
  std::string img =
      Bytes().u64(1).u32(1).f64(1).f64(0).f64(0).f64(0).f64(0).f64(0).f64(0).u32(1).raw("a.png").u8(0).u64(huge).s;
  expect_refused([&] { parse_images_bin(img, "images.bin"); }, "images.bin", "image 1 (a.png): num_points2D",
                 "claims 1152921504606846976 points2D");
  std::string pts = Bytes().u64(1).u64(9).f64(0).f64(0).f64(0).u8(1).u8(2).u8(3).f64(0).u64(huge).s;
  expect_refused([&] { parse_points3d_bin(pts, "points3D.bin"); }, "points3D.bin", "point 9: track_length");
}

TEST(ColmapModel, ImageCameraMustExist) {
  RefModel ref = reference();
  ref.images[1].camera = 99;
  ref.images[1].name = "IMG_0012.JPG";
  ScratchDir b, t;
  write_bin(b.path(), ref);
  write_txt(t.path(), ref);
  expect_refused([&] { read_colmap_model(b.path()); }, b / "images.bin", "image 12 (IMG_0012.JPG): camera_id",
                 "camera 99 is not in cameras.bin");
  expect_refused([&] { read_colmap_model(t.path()); }, t / "images.txt", "image 12 (IMG_0012.JPG): camera_id",
                 "camera 99 is not in cameras.txt");
}

TEST(ColmapModel, DuplicateIds) {
  RefModel ref = reference();
  ref.cameras[1].id = ref.cameras[0].id;
  expect_refused([&] { parse_cameras_bin(cameras_bin(ref), "cameras.bin"); }, "cameras.bin", "camera 1: camera_id",
                 "duplicate");
  expect_refused([&] { parse_cameras_txt(cameras_txt(ref), "cameras.txt"); }, "cameras.txt", "camera 1", "duplicate");
  ref = reference();
  ref.images[2].id = 3;
  expect_refused([&] { parse_images_bin(images_bin(ref), "images.bin"); }, "images.bin", "image 3 (c.png)",
                 "duplicate");
  expect_refused([&] { parse_images_txt(images_txt(ref), "images.txt"); }, "images.txt", "image 3 (c.png)",
                 "duplicate");
  ref = reference();
  ref.points[2].id = 100;
  expect_refused([&] { parse_points3d_bin(points_bin(ref), "points3D.bin"); }, "points3D.bin", "point 100",
                 "duplicate");
  expect_refused([&] { parse_points3d_txt(points_txt(ref), "points3D.txt"); }, "points3D.txt", "point 100",
                 "duplicate");
}

TEST(ColmapModel, TrailingBytes) {
  const RefModel ref = reference();
  expect_refused([&] { parse_cameras_bin(cameras_bin(ref) + "x", "cameras.bin"); }, "cameras.bin", "byte", "trailing");
  expect_refused([&] { parse_images_bin(images_bin(ref) + std::string(1, '\0'), "images.bin"); }, "images.bin", "byte",
                 "trailing");
  const std::string p = points_bin(ref);
  expect_refused([&] { parse_points3d_bin(p + p, "points3D.bin"); }, "points3D.bin", "byte " + std::to_string(p.size()),
                 "trailing");
}

TEST(ColmapModel, TextFieldCounts) {
  expect_refused([&] { parse_cameras_txt("1 PINHOLE 64 48 50 50 32\n", "cameras.txt"); }, "cameras.txt",
                 "line 1: camera 1: params", "PINHOLE has 4 parameters, the line gives 3");
  expect_refused([&] { parse_cameras_txt("# c\n1 OPENCV 64 48 1 2 3 4 5 6 7 8 9\n", "cameras.txt"); }, "cameras.txt",
                 "line 2: camera 1: params", "OPENCV has 8 parameters, the line gives 9");
  expect_refused([&] { parse_cameras_txt("1 PINHOLE 64\n", "cameras.txt"); }, "cameras.txt", "line 1",
                 "expected CAMERA_ID MODEL WIDTH HEIGHT");
  expect_refused([&] { parse_images_txt("1 1 0 0 0 0 0 0 1\n\n", "images.txt"); }, "images.txt", "line 1",
                 "got 9 fields");
  expect_refused([&] { parse_images_txt("1 1 0 0 0 0 0 0 1 a.png\n1 2 3 4\n", "images.txt"); }, "images.txt",
                 "line 2: image 1 (a.png): points2D", "triples");
  expect_refused([&] { parse_images_txt("1 1 0 0 0 0 0 0 1 a.png\n1 2 -2\n", "images.txt"); }, "images.txt",
                 "POINT3D_ID", "whole number");
  expect_refused([&] { parse_points3d_txt("1 0 0 0 1 2 3 0.5 7\n", "points3D.txt"); }, "points3D.txt", "line 1",
                 "pairs");
  expect_refused([&] { parse_points3d_txt("1 0 0 0 1 2 256 0.5\n", "points3D.txt"); }, "points3D.txt", "point 1: rgb",
                 "out of range");
  expect_refused([&] { parse_cameras_txt("x PINHOLE 1 1 1 1 1 1\n", "cameras.txt"); }, "cameras.txt",
                 "line 1: CAMERA_ID", "whole number");
  expect_refused([&] { parse_cameras_txt("4294967296 PINHOLE 1 1 1 1 1 1\n", "cameras.txt"); }, "cameras.txt",
                 "line 1: CAMERA_ID", "out of range");
}

TEST(ColmapModel, NonFiniteValues) {
  const double nan = std::numeric_limits<double>::quiet_NaN(), inf = std::numeric_limits<double>::infinity();
  RefModel ref = reference();
  ref.cameras[1].params[5] = nan;
  expect_refused([&] { parse_cameras_bin(cameras_bin(ref), "cameras.bin"); }, "cameras.bin", "camera 7: params[5]",
                 "non-finite");
  ref = reference();
  ref.images[0].q[2] = inf;
  expect_refused([&] { parse_images_bin(images_bin(ref), "images.bin"); }, "images.bin", "image 3 (IMG_0003.JPG): qvec",
                 "non-finite");
  ref = reference();
  ref.images[2].t[1] = -inf;
  expect_refused([&] { parse_images_bin(images_bin(ref), "images.bin"); }, "images.bin", "image 5 (c.png): tvec",
                 "non-finite");
  ref = reference();
  ref.points[1].xyz[0] = nan;
  expect_refused([&] { parse_points3d_bin(points_bin(ref), "points3D.bin"); }, "points3D.bin", "point 101: xyz",
                 "non-finite");
  expect_refused([&] { parse_cameras_txt("1 PINHOLE 64 48 50 nan 32 24\n", "cameras.txt"); }, "cameras.txt",
                 "camera 1: params[1]", "non-finite");
  expect_refused([&] { parse_cameras_txt("1 PINHOLE 64 48 50 1e999 32 24\n", "cameras.txt"); }, "cameras.txt",
                 "camera 1: params[1]", "out of range");
  expect_refused([&] { parse_images_txt("1 1 0 0 0 inf 0 0 1 a.png\n\n", "images.txt"); }, "images.txt",
                 "image 1: tvec", "non-finite");
  expect_refused([&] { parse_points3d_txt("1 0 -inf 0 1 2 3 0.5\n", "points3D.txt"); }, "points3D.txt", "point 1: xyz",
                 "non-finite");
}

TEST(ColmapModel, SizesQuaternionsAndNames) {
  RefModel ref = reference();
  ref.cameras[0].width = 0;
  expect_refused([&] { parse_cameras_bin(cameras_bin(ref), "cameras.bin"); }, "cameras.bin", "camera 1: width");
  ref = reference();
  ref.cameras[1].height = (uint64_t{1} << 20) + 1;
  expect_refused([&] { parse_cameras_bin(cameras_bin(ref), "cameras.bin"); }, "cameras.bin", "camera 7: height");
  ref.cameras[1].height = uint64_t{1} << 20;  // the largest accepted
  EXPECT_EQ(parse_cameras_bin(cameras_bin(ref), "cameras.bin")[1].height, uint64_t{1} << 20);
  expect_refused([&] { parse_cameras_txt("1 PINHOLE 64 99999999999999999999 1 1 1 1\n", "cameras.txt"); },
                 "cameras.txt", "camera 1: height", "out of range");

  ref = reference();
  ref.images[1].q = {0, 0, 0, 0};
  expect_refused([&] { parse_images_bin(images_bin(ref), "images.bin"); }, "images.bin", "image 12", "not a rotation");
  ref.images[1].q = {1e-7, 0, 0, 0};
  expect_refused([&] { parse_images_txt(images_txt(ref), "images.txt"); }, "images.txt", "image 12", "not a rotation");
  ref.images[1].q = {1e-300, 1e-300, 0, 0};  // tiny but would underflow if squared naively: still refused
  expect_refused([&] { parse_images_bin(images_bin(ref), "images.bin"); }, "images.bin", "qvec");
  ref.images[1].q = {1e200, 0, 0, 1e200};  // huge: squared naively it overflows; scaled it is fine
  const auto im = parse_images_bin(images_bin(ref), "images.bin");
  EXPECT_NEAR(im[1].qvec[0], std::sqrt(0.5), 1e-15);
  EXPECT_NEAR(im[1].qvec[3], std::sqrt(0.5), 1e-15);

  ref = reference();
  ref.images[0].name = "";
  expect_refused([&] { parse_images_bin(images_bin(ref), "images.bin"); }, "images.bin", "image 3 (): name", "empty");
  expect_refused([&] { parse_images_txt("1 1 0 0 0 0 0 0 1 a\0b.png\n\n"s, "images.txt"); }, "images.txt",
                 "image 1 (a?b.png): name", "NUL");
  // A name with a newline (binary) is kept, but messages show it on one line.
  ref = reference();
  ref.images[0].name = "bad\nname";
  EXPECT_EQ(parse_images_bin(images_bin(ref), "images.bin")[0].name, "bad\nname");
  ref.images[0].t[0] = std::numeric_limits<double>::infinity();
  expect_refused([&] { parse_images_bin(images_bin(ref), "images.bin"); }, "images.bin", "image 3 (bad?name): tvec");
}

TEST(ColmapModel, ModelTable) {
  EXPECT_EQ(colmap_model_params("SIMPLE_PINHOLE"), 3);
  EXPECT_EQ(colmap_model_params("PINHOLE"), 4);
  EXPECT_EQ(colmap_model_params("OPENCV"), 8);
  EXPECT_EQ(colmap_model_params("FULL_OPENCV"), 12);
  EXPECT_EQ(colmap_model_params("THIN_PRISM_FISHEYE"), 12);
  EXPECT_EQ(colmap_model_params("pinhole"), -1);
  EXPECT_EQ(colmap_model_params(""), -1);
  EXPECT_STREQ(colmap_model_name(4), "OPENCV");
  EXPECT_STREQ(colmap_model_name(10), "THIN_PRISM_FISHEYE");
  EXPECT_STREQ(colmap_model_name(11), "");
  EXPECT_STREQ(colmap_model_name(-1), "");
  // Every model id reads its own parameter count from a binary file.
  const int counts[] = {3, 4, 4, 5, 8, 8, 12, 5, 4, 5, 12};
  Bytes b;
  b.u64(11);
  for (int id = 0; id < 11; ++id) {
    b.u32(static_cast<uint32_t>(id + 1)).i32(id).u64(8).u64(6);
    for (int k = 0; k < counts[id]; ++k) b.f64(k);
  }
  const auto cams = parse_cameras_bin(b.s, "cameras.bin");
  ASSERT_EQ(cams.size(), 11u);
  for (int id = 0; id < 11; ++id) {
    EXPECT_EQ(cams[static_cast<size_t>(id)].model, colmap_model_name(id));
    EXPECT_EQ(static_cast<int>(cams[static_cast<size_t>(id)].params.size()), counts[id]);
  }
}
