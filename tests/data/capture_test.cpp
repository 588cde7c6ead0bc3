// Real-capture loaders on small captures written here (COLMAP text model, LLFF poses_bounds.npy,
// nerfstudio transforms.json): every loaded camera is checked against a projection done by hand in
// the format's own convention (COLMAP: world-to-camera, OpenCV axes, quaternion; LLFF: columns
// down/right/back; nerfstudio: OpenGL camera-to-world through an OpenCV or fisheye lens). A world
// point projected by hand to a pixel must lie on the ray the loader casts through that pixel, in
// the scene frame. Also: the every-8th split by image name, nerfstudio's own split, pre-downscaled
// images_N folders, per-image LLFF bounds, and the real captures in captures/ (under the checkout, or beside it) when
// present.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <functional>
#include <map>
#include <sstream>

#include "data/dataset.h"
#include "jpeg_writer.h"
#include "test_geometry.h"
#include "test_util.h"
#include "util/errors.h"
#include "util/image_io.h"
#include "data/data_config.h"

using namespace ablenerf;
namespace fs = std::filesystem;

namespace {

using test::cross3;
using test::dot3;
using test::Frame3;
using test::look_at;
using test::sub3;
using test::unit3;
using test::V3;

// Cameras on a tilted circle around `target` (radius 4, 1.5 above it along `up`).
std::vector<Frame3> ring(int n, const V3& target, const V3& up) {
  const V3 a = unit3(cross3(up, {0.3, 0.1, 0.9})), b = cross3(unit3(up), a);
  std::vector<Frame3> out;
  for (int i = 0; i < n; ++i) {
    const double th = 2 * M_PI * i / n;
    V3 eye;
    for (int c = 0; c < 3; ++c)
      eye[static_cast<size_t>(c)] =
          target[static_cast<size_t>(c)] +
          4 * (std::cos(th) * a[static_cast<size_t>(c)] + std::sin(th) * b[static_cast<size_t>(c)]) +
          1.5 * unit3(up)[static_cast<size_t>(c)];
    out.push_back(look_at(eye, target, up));
  }
  return out;
}

// Pixel coordinates (COLMAP / OpenCV convention: the top-left pixel's centre is (0.5, 0.5)) of
// the normalised image-plane point (x, y) (x right, y down) through the OpenCV radial-tangential
// or the fisheye (Kannala-Brandt, OpenCV's cv::fisheye) model.
struct Lens {
  double fx, fy, cx, cy;
  double k1 = 0, k2 = 0, k3 = 0, k4 = 0, p1 = 0, p2 = 0;
  bool fisheye = false;
  std::pair<double, double> project(double x, double y) const {
    double xd, yd;
    if (fisheye) {
      const double r = std::sqrt(x * x + y * y), th = std::atan(r), t2 = th * th;
      const double thd = th * (1 + k1 * t2 + k2 * t2 * t2 + k3 * t2 * t2 * t2 + k4 * t2 * t2 * t2 * t2);
      xd = r > 0 ? x * thd / r : x, yd = r > 0 ? y * thd / r : y;
    } else {
      const double r2 = x * x + y * y, radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
      xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x);
      yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y;
    }
    return {fx * xd + cx, fy * yd + cy};
  }
};

// The loader's ray through continuous pixel coordinate (u, v) of image i of `split` passes within
// `tol` of `world` (capture coordinates) moved into the scene frame, in front of the camera.
void expect_ray_hits(const Dataset& ds, const Split& split, int64_t i, double u, double v, const V3& world, double tol,
                     const std::string& what) {
  const auto col = torch::tensor({u - 0.5}, torch::kFloat64), row = torch::tensor({v - 0.5}, torch::kFloat64);
  const Rays r = rays_for_pixels(split.c2w[i].unsqueeze(0).to(torch::kFloat64), col, row,
                                 CameraTable::of({split.cameras[static_cast<size_t>(i)]}));
  const V3 p = ds.scene.point_to_scene(world);
  const auto pt = torch::tensor({p[0], p[1], p[2]}, torch::kFloat64);
  const auto o = r.origins[0].to(torch::kFloat64), d = r.directions[0].to(torch::kFloat64);
  const double dist = torch::cross(pt - o, d, 0).norm().item<double>() / d.norm().item<double>();
  EXPECT_LT(dist, tol) << what << " (pixel " << u << ", " << v << ")";
  EXPECT_GT((pt - o).dot(d).item<double>(), 0) << what << ": the point is behind the camera";
}

// Opaque RGB image files of one colour.
void write_image(const std::string& path, int w, int h, int value) {
  fs::create_directories(fs::path(path).parent_path());
  write_png(path, torch::full({h, w, 3}, value, torch::kUInt8));
}

// World-to-camera rotation (rows: the camera's OpenCV axes x right, y down, z forward) as a unit
// quaternion (w, x, y, z), by Shepperd's method.
std::array<double, 4> quaternion_of(const double R[3][3]) {
  const double tr = R[0][0] + R[1][1] + R[2][2];
  std::array<double, 4> q{};
  if (tr > 0) {
    const double s = 2 * std::sqrt(1 + tr);
    q = {s / 4, (R[2][1] - R[1][2]) / s, (R[0][2] - R[2][0]) / s, (R[1][0] - R[0][1]) / s};
  } else if (R[0][0] > R[1][1] && R[0][0] > R[2][2]) {
    const double s = 2 * std::sqrt(1 + R[0][0] - R[1][1] - R[2][2]);
    q = {(R[2][1] - R[1][2]) / s, s / 4, (R[0][1] + R[1][0]) / s, (R[0][2] + R[2][0]) / s};
  } else if (R[1][1] > R[2][2]) {
    const double s = 2 * std::sqrt(1 + R[1][1] - R[0][0] - R[2][2]);
    q = {(R[0][2] - R[2][0]) / s, (R[0][1] + R[1][0]) / s, s / 4, (R[1][2] + R[2][1]) / s};
  } else {
    const double s = 2 * std::sqrt(1 + R[2][2] - R[0][0] - R[1][1]);
    q = {(R[1][0] - R[0][1]) / s, (R[0][2] + R[2][0]) / s, (R[1][2] + R[2][1]) / s, s / 4};
  }
  return q;
}

// The file name the loader recorded for image i of a split.
std::string name_of(const Split& s, int64_t i) { return fs::path(s.files[static_cast<size_t>(i)]).filename().string(); }

const V3 kTarget{1.0, 2.0, 3.0};
const V3 kUp = unit3({0.2, -0.3, 1.0});
// World points near the target (what the cameras see).
const std::vector<V3> kPoints{{1.0, 2.0, 3.0}, {1.4, 1.7, 3.2}, {0.6, 2.3, 2.7}, {1.2, 2.5, 3.4}, {0.8, 1.6, 2.9}};

// LLFF's poses_bounds.npy in `dir` for `frames`: row i = the 3x5 matrix [down | right | back | eye |
// (h, w, f)] row-major, then frame i's near and far, `bounds(i)`.
void write_llff_npy(const fs::path& dir, const std::vector<Frame3>& frames, const std::array<double, 3>& hwf,
                    const std::function<std::pair<double, double>(size_t)>& bounds) {
  std::vector<double> rows;
  for (size_t i = 0; i < frames.size(); ++i) {
    const Frame3& f = frames[i];
    for (size_t r = 0; r < 3; ++r)
      for (double v : {-f.up[r], f.right[r], f.back[r], f.eye[r], hwf[r]}) rows.push_back(v);
    const auto [near, far] = bounds(i);
    rows.push_back(near);
    rows.push_back(far);
  }
  test::write_file(dir / "poses_bounds.npy", test::llff_poses_bounds_npy(rows));
}

// Every point of kPoints, projected by hand through frame `f` as an LLFF camera (looking along
// -back, x along right, y along down) and `lens`, lies on the loader's ray through that pixel of
// image i of `split`.
void expect_llff_projection(const Dataset& ds, const Split& split, int64_t i, const Frame3& f, const Lens& lens,
                            const std::string& what) {
  for (const V3& X : kPoints) {
    const V3 d = sub3(X, f.eye);
    const double z = -dot3(d, f.back);
    const V3 down_axis{-f.up[0], -f.up[1], -f.up[2]};
    const auto [u, v] = lens.project(dot3(d, f.right) / z, dot3(d, down_axis) / z);
    expect_ray_hits(ds, split, i, u, v, X, 2e-5, what);
  }
}

}  // namespace

TEST(Captures, ColmapPosesAndLensesMatchAHandProjection) {
  test::TempDir t;
  const int W = 64, H = 48;
  // Camera 1: OPENCV; camera 2: SIMPLE_RADIAL. Images named so that their sorted order differs
  // from the id order and from the order images.txt lists them in.
  const Lens cam1{60, 58, 31.2, 24.9, 0.05, -0.02, 0, 0, 0.004, -0.003};
  const Lens cam2{55, 55, 32, 24, -0.08};
  std::ostringstream cams, imgs, pts;
  cams << "# cameras\n1 OPENCV " << W << " " << H << " 60 58 31.2 24.9 0.05 -0.02 0.004 -0.003\n"
       << "2 SIMPLE_RADIAL " << W << " " << H << " 55 32 24 -0.08\n";
  const auto frames = ring(9, kTarget, kUp);
  std::map<std::string, std::pair<Frame3, Lens>> truth;
  for (int i = 8; i >= 0; --i) {
    const Frame3& f = frames[static_cast<size_t>(i)];
    // World-to-camera: rows are the OpenCV axes (right, down = -up, forward = -back); t = -R eye.
    const double R[3][3] = {
        {f.right[0], f.right[1], f.right[2]}, {-f.up[0], -f.up[1], -f.up[2]}, {-f.back[0], -f.back[1], -f.back[2]}};
    const auto q = quaternion_of(R);
    V3 tv;
    for (int r = 0; r < 3; ++r)
      tv[static_cast<size_t>(r)] = -(R[r][0] * f.eye[0] + R[r][1] * f.eye[1] + R[r][2] * f.eye[2]);
    const int cam = i % 2 ? 2 : 1;
    const std::string name = "v" + std::to_string((i * 5) % 9) + ".png";  // v0, v5, v1, v6, ...
    // COLMAP does not require a normalised quaternion: write it scaled by 2.
    imgs << i + 1 << " " << 2 * q[0] << " " << 2 * q[1] << " " << 2 * q[2] << " " << 2 * q[3] << " " << tv[0] << " "
         << tv[1] << " " << tv[2] << " " << cam << " " << name << "\n\n";
    write_image(t / ("images/" + name), W, H, 10 * i);
    truth[name] = {f, cam == 1 ? cam1 : cam2};
  }
  for (size_t p = 0; p < kPoints.size(); ++p)
    pts << p + 1 << " " << kPoints[p][0] << " " << kPoints[p][1] << " " << kPoints[p][2] << " 255 0 0 0.5\n";
  test::write_file(t / "sparse/0/cameras.txt", cams.str());
  test::write_file(t / "sparse/0/images.txt", imgs.str());
  test::write_file(t / "sparse/0/points3D.txt", pts.str());
  test::write_file(t / "sparse/0/project.ini", "[General]\n");  // COLMAP's mapper leaves it there

  LoadOptions o;
  o.scene = SceneKind::Bounded;
  const Dataset ds = Dataset::load(t.path(), o);
  EXPECT_EQ(ds.format, "colmap");
  ASSERT_EQ(ds.split("test").size(), 2);  // v0 and v8: every 8th by name
  EXPECT_EQ(name_of(ds.split("test"), 0), "v0.png");
  EXPECT_EQ(name_of(ds.split("test"), 1), "v8.png");
  EXPECT_EQ(ds.split("train").size(), 7);
  EXPECT_EQ(ds.scene.bounds_source, "points");
  int checked = 0;
  for (const auto& [sname, split] : ds.splits) {
    for (int64_t i = 0; i < split.size(); ++i) {
      const auto& [f, lens] = truth.at(name_of(split, i));
      EXPECT_EQ(split.cameras[static_cast<size_t>(i)].model, LensModel::RadialTangential);
      // The image's pixels are the ones written for it (10 * original index).
      for (const V3& X : kPoints) {
        const V3 d = sub3(X, f.eye);
        const double z = -dot3(d, f.back);
        const auto [u, v] = lens.project(dot3(d, f.right) / z, -dot3(d, f.up) / z);
        ASSERT_TRUE(u > 0 && u < W && v > 0 && v < H) << "test geometry: point outside the image";
        expect_ray_hits(ds, split, i, u, v, X, 2e-5, sname + " " + name_of(split, i));
        ++checked;
      }
    }
  }
  EXPECT_EQ(checked, 9 * static_cast<int>(kPoints.size()));
  // The centre of the scene frame is the point the cameras look at; near comes from the points
  // (every point is ~4.3 units in front of every camera: half of that, in scene units).
  const V3 c = ds.scene.point_to_scene(kTarget);
  EXPECT_LT(std::sqrt(dot3(c, c)), 1e-6);
  const double dist = std::sqrt(16 + 1.5 * 1.5);
  EXPECT_NEAR(ds.scene.scale, 1 / dist, 1e-6);  // poses are float32
  EXPECT_GT(ds.scene.near, 0.5 * (dist - 0.7) / dist);
  EXPECT_LT(ds.scene.near, 0.5 * (dist + 0.7) / dist);
}

TEST(Captures, LlffAxesBoundsAndPrescaledImagesMatchAHandProjection) {
  test::TempDir t;
  const int W = 64, H = 48;
  const auto frames = ring(10, kTarget, kUp);
  // The npy's size is twice the stored images' (LLFF keeps the size the poses were computed at):
  // the loaded focal must be halved.
  write_llff_npy(t.path(), frames, {2.0 * H, 2.0 * W, 2 * 50.0}, [](size_t i) {
    return std::make_pair(3.0 + 0.1 * static_cast<double>(i), 5.0 + 0.2 * static_cast<double>(i));
  });
  for (size_t i = 0; i < frames.size(); ++i) {
    const std::string stem = "IMG_" + std::to_string(100 + i);
    write_image(t / ("images/" + stem + ".png"), W, H, 100);
    write_image(t / ("images_2/" + stem + ".png"), W / 2, H / 2, 200);  // LLFF's minified copies
  }
  LoadOptions o;
  o.scene = SceneKind::Bounded;
  for (const int down : {1, 2}) {
    SCOPED_TRACE("downscale " + std::to_string(down));
    o.downscale = down;
    const Dataset ds = Dataset::load(t.path(), o);
    EXPECT_EQ(ds.format, "llff");
    ASSERT_EQ(ds.split("test").size(), 2);  // images 0 and 8
    EXPECT_EQ(name_of(ds.split("test"), 1), "IMG_108.png");
    EXPECT_EQ(ds.intrinsics.width, W / down);
    EXPECT_NEAR(ds.intrinsics.fx, 50.0 / down, 1e-9);
    // downscale 2 reads images_2 (value 200), not a box-downscale of images/ (value 100).
    EXPECT_NEAR(ds.split("train").images.mean().item<double>(), (down == 1 ? 100 : 200) / 255.0, 1e-6);
    {  // and so does one frame read on its own (the viewer's error mode)
      const Capture js = read_capture(t.path(), {}, down);
      const auto rgba = frame_photo_rgba(js.splits.front().frames.front(), js.height, js.width, down);
      ASSERT_EQ(rgba.sizes(), (std::vector<int64_t>{H / down, W / down, 4}));
      EXPECT_NEAR(rgba.slice(2, 0, 3).min().item<double>(), (down == 1 ? 100 : 200) / 255.0, 1e-6);
      EXPECT_NEAR(rgba.slice(2, 0, 3).max().item<double>(), (down == 1 ? 100 : 200) / 255.0, 1e-6);
    }
    // Near/far from the per-image bounds (3.0 .. 6.8 capture units), with the loader's margins.
    EXPECT_EQ(ds.scene.bounds_source, "llff bounds");
    EXPECT_NEAR(ds.scene.near, 0.9 * 3.0 * ds.scene.scale, 1e-9);
    EXPECT_NEAR(ds.scene.far, 1.1 * 6.8 * ds.scene.scale, 1e-9);
    const Lens lens{50.0 / down, 50.0 / down, 0.5 * W / down, 0.5 * H / down};
    for (const auto& [sname, split] : ds.splits) {
      for (int64_t i = 0; i < split.size(); ++i) {
        const int idx = std::stoi(name_of(split, i).substr(4, 3)) - 100;
        expect_llff_projection(ds, split, i, frames[static_cast<size_t>(idx)], lens, sname + " " + name_of(split, i));
      }
    }
  }
  // A pose count that differs from the image count names the npy's shape.
  fs::remove(t / "images/IMG_105.png");
  test::expect_input_error([&] { Dataset::load(t.path(), o); }, t / "poses_bounds.npy", "shape", "9 images", true);
}

// LLFF's release (nerf_llff_data) names its minified copies images_N/image000.png, ... while images/
// keeps the camera's names (IMG_4026.JPG, ...): NeRF's load_llff pairs the npy's rows with the copies
// in sorted order. Each copy here has its own value, so a frame's pixels say which copy it got and its
// rays say which row; then the capture with its copies alone (no images/) loads the same.
TEST(Captures, LlffReleaseCopiesPairByOrderAndLoadWithoutThePhotos) {
  test::TempDir t;
  const int W = 64, H = 48;
  const auto frames = ring(10, kTarget, kUp);
  // The npy at the photos' size, as LLFF's release.
  write_llff_npy(t.path(), frames, {1.0 * H, 1.0 * W, 50.0}, [](size_t) { return std::make_pair(3.0, 6.0); });
  const auto copy_value = [](int i) { return 20 + 10 * i; };
  for (int i = 0; i < 10; ++i) {
    write_image(t / ("images/IMG_" + std::to_string(4026 + i) + ".png"), W, H, 5);
    char name[32];
    std::snprintf(name, sizeof name, "images_2/image%03d.png", i);
    write_image(t / name, W / 2, H / 2, copy_value(i));
  }
  LoadOptions o;
  o.scene = SceneKind::Bounded;
  o.downscale = 2;
  const auto check = [&](const std::string& what) {
    SCOPED_TRACE(what);
    const Dataset ds = Dataset::load(t.path(), o);
    EXPECT_EQ(ds.format, "llff");
    EXPECT_EQ(ds.intrinsics.width, W / 2);
    EXPECT_NEAR(ds.intrinsics.fx, 25.0, 1e-9);
    ASSERT_EQ(ds.split("test").size(), 2);
    EXPECT_EQ(name_of(ds.split("test"), 0), "image000.png");
    EXPECT_EQ(name_of(ds.split("test"), 1), "image008.png");
    const Lens lens{25.0, 25.0, 0.5 * W / 2, 0.5 * H / 2};
    for (const auto& [sname, split] : ds.splits) {
      for (int64_t k = 0; k < split.size(); ++k) {
        const int idx = std::stoi(name_of(split, k).substr(5, 3));
        EXPECT_NEAR(split.images[k].mean().item<double>(), copy_value(idx) / 255.0, 1e-6);
        expect_llff_projection(ds, split, k, frames[static_cast<size_t>(idx)], lens, sname + " " + name_of(split, k));
      }
    }
  };
  check("images/ and images_2/ named apart");
  fs::remove_all(t / "images");
  check("images_2/ alone");
  // Without the photos, only the copies' own scale loads; any other names the missing images/.
  o.downscale = 1;
  test::expect_input_error([&] { Dataset::load(t.path(), o); }, t.path(), "images", "images_N/", true);
  o.downscale = 4;
  test::expect_input_error([&] { Dataset::load(t.path(), o); }, t.path(), "images", "images_N/", true);
}

TEST(Captures, NerfstudioFisheyeOwnSplitAndPrescaledCopies) {
  test::TempDir t;
  const int W = 80, H = 60;
  const Lens lens{40, 41, 39.5, 30.5, 0.03, -0.01, 0.002, -0.0005, 0, 0, true};
  const auto frames = ring(6, kTarget, kUp);
  std::ostringstream js;
  js.precision(17);
  js << "{\"camera_model\": \"OPENCV_FISHEYE\", \"w\": " << W << ", \"h\": " << H
     << ", \"fl_x\": 40, \"fl_y\": 41, \"cx\": 39.5, \"cy\": 30.5, \"k1\": 0.03, \"k2\": -0.01, \"k3\": 0.002, "
        "\"k4\": -0.0005, \"applied_transform\": [[1,0,0,0],[0,0,1,0],[0,-1,0,0]],\n\"frames\": [";
  for (size_t i = 0; i < frames.size(); ++i) {
    const Frame3& f = frames[i];
    js << (i ? "," : "") << "{\"file_path\": \"images/frame_" << i << ".png\", \"transform_matrix\": [";
    for (int r = 0; r < 3; ++r) {
      const size_t rr = static_cast<size_t>(r);
      js << "[" << f.right[rr] << "," << f.up[rr] << "," << f.back[rr] << "," << f.eye[rr] << "],";
    }
    js << "[0,0,0,1]]}";
    write_image(t / ("images/frame_" + std::to_string(i) + ".png"), W, H, 30);
    write_image(t / ("images_2/frame_" + std::to_string(i) + ".png"), W / 2, H / 2, 60);
  }
  js << "],\n\"train_filenames\": [\"images/frame_0.png\", \"images/frame_2.png\", \"images/frame_3.png\", "
        "\"images/frame_5.png\"],\n\"test_filenames\": [\"images/frame_4.png\", \"./images/frame_1.png\"]}";
  test::write_file(t / "transforms.json", js.str());
  LoadOptions o;
  o.scene = SceneKind::Unbounded;
  o.downscale = 2;
  const Dataset ds = Dataset::load(t.path(), o);
  EXPECT_EQ(ds.format, "nerfstudio");
  ASSERT_EQ(ds.split("train").size(), 4);
  ASSERT_EQ(ds.split("test").size(), 2);
  EXPECT_EQ(name_of(ds.split("test"), 0), "frame_4.png");  // the capture's order is kept
  EXPECT_EQ(name_of(ds.split("test"), 1), "frame_1.png");
  EXPECT_NEAR(ds.split("test").images.mean().item<double>(), 60 / 255.0, 1e-6);  // images_2 read
  const Intrinsics& k = ds.split("test").cameras[0];
  EXPECT_EQ(k.model, LensModel::Fisheye);
  EXPECT_EQ(k.width, W / 2);
  EXPECT_NEAR(k.fx, 20, 1e-12);
  EXPECT_NEAR(k.cy, 15.25, 1e-12);
  const Lens half{20, 20.5, 19.75, 15.25, lens.k1, lens.k2, lens.k3, lens.k4, 0, 0, true};
  for (const auto& [sname, split] : ds.splits) {
    for (int64_t i = 0; i < split.size(); ++i) {
      const std::string n = name_of(split, i);
      const Frame3& f = frames[static_cast<size_t>(n[6] - '0')];
      for (const V3& X : kPoints) {
        const V3 d = sub3(X, f.eye);
        const double z = -dot3(d, f.back);
        const auto [u, v] = half.project(dot3(d, f.right) / z, -dot3(d, f.up) / z);
        expect_ray_hits(ds, split, i, u, v, X, 2e-5, sname + " " + n);
      }
    }
  }
  // nerfstudio's sparse point cloud (ply_file_path) gives the near bound, as COLMAP's points do.
  EXPECT_EQ(ds.scene.bounds_source, "cameras");
  {
    std::string ply = "ply\nformat ascii 1.0\nelement vertex " + std::to_string(kPoints.size()) +
                      "\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
    for (const V3& X : kPoints)
      ply += std::to_string(X[0]) + " " + std::to_string(X[1]) + " " + std::to_string(X[2]) + "\n";
    test::write_file(t / "sparse_pc.ply", ply);
    auto with_ply = js.str();
    with_ply.replace(with_ply.find("\"camera_model\""), 0, "\"ply_file_path\": \"sparse_pc.ply\", ");
    test::write_file(t / "transforms.json", with_ply);
    const Dataset dp = Dataset::load(t.path(), o);
    EXPECT_EQ(dp.scene.bounds_source, "points");
    EXPECT_GT(dp.scene.near, 0.05);  // half the ~4.3 units to the points, in scene units: ~0.5
  }
  // A test list naming a file that exists but is no frame's image.
  auto text = js.str();
  text.replace(text.find("./images/frame_1"), 16, "images_2/frame_1");
  test::write_file(t / "transforms.json", text);
  test::expect_input_error([&] { Dataset::load(t.path(), o); }, t / "transforms.json", "test_filenames[1]",
                           "no frame has this file_path", true);
}

TEST(Captures, JpegExifOrientationIsAppliedWhenTheCaptureSizeIsTheUprightOne) {
  // A portrait photo stored landscape (16 wide, 8 high) with EXIF orientation 6 ("rotate 90 degrees
  // clockwise to display"): upright it is 8 wide, 16 high, and upright pixel (r, c) is stored
  // pixel (7 - c, r).
  test::TempDir t;
  const int sw = 16, sh = 8;
  std::vector<uint8_t> px(static_cast<size_t>(sw * sh * 3));
  for (int y = 0; y < sh; ++y)
    for (int x = 0; x < sw; ++x)
      for (int ch = 0; ch < 3; ++ch)
        px[static_cast<size_t>((y * sw + x) * 3 + ch)] = static_cast<uint8_t>(ch == 0   ? 20 + 12 * x
                                                                              : ch == 1 ? 30 + 25 * y
                                                                                        : 90);
  test::JpegOptions jo;
  jo.app1 = test::exif_payload(true, 6);
  const std::string jpeg = test::encode_jpeg(px, sw, sh, jo);
  fs::create_directories(t / "images");
  for (int i = 0; i < 2; ++i) test::write_file(t / ("images/p" + std::to_string(i) + ".jpg"), jpeg);
  const auto json_with = [&](int w, int h) {
    return "{\"fl_x\": 10, \"w\": " + std::to_string(w) + ", \"h\": " + std::to_string(h) +
           ", \"frames\": [{\"file_path\": \"images/p0.jpg\", \"transform_matrix\": "
           "[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]},"
           "{\"file_path\": \"images/p1.jpg\", \"transform_matrix\": [[1,0,0,1],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]}";
  };
  // The capture says 8x16: its poses were made on the upright image, which the loader produces.
  test::write_file(t / "transforms.json", json_with(8, 16));
  Dataset ds = Dataset::load(t.path());
  const auto im = ds.split("train").images[0];  // (16, 8, 3), in [0, 1]
  ASSERT_EQ(im.sizes(), (std::vector<int64_t>{16, 8, 3}));
  double worst = 0;
  for (int r = 0; r < 16; ++r)
    for (int c = 0; c < 8; ++c)
      for (int ch = 0; ch < 3; ++ch)
        worst = std::max(
            worst, std::abs(im[r][c][ch].item<double>() * 255 - px[static_cast<size_t>(((7 - c) * sw + r) * 3 + ch)]));
  EXPECT_LT(worst, 6);  // JPEG at quality 100 with 4:4:4 sampling: a few levels of rounding
  // One frame read on its own (the viewer's error mode): the loader's upright pixels, alpha 1.
  {
    const Capture js = read_capture(t.path(), {}, 1);
    const auto rgba = frame_photo_rgba(js.splits.front().frames.front(), js.height, js.width, 1);  // train's first
    ASSERT_EQ(rgba.sizes(), (std::vector<int64_t>{16, 8, 4}));
    EXPECT_TRUE(torch::equal(rgba.slice(2, 0, 3), im));
    EXPECT_EQ(rgba.select(2, 3).min().item<float>(), 1.0f);
  }
  // The capture says 16x8: the stored pixels, untouched.
  test::write_file(t / "transforms.json", json_with(16, 8));
  ds = Dataset::load(t.path());
  EXPECT_EQ(ds.split("train").images[0].sizes(), (std::vector<int64_t>{8, 16, 3}));
  // A size that is neither: refused, naming the image and the sizes.
  test::write_file(t / "transforms.json", json_with(12, 8));
  // (frame 1 is the first decoded: the train split comes first, frame 0 is held out for test).
  test::expect_input_error([&] { Dataset::load(t.path()); }, fs::canonical(t / "images/p1.jpg").string(),
                           "frames[1].file_path", "12x8", true);
}

// JPEGs loaded at 1/f are decoded reduced inside libjpeg (LoadOptions::jpeg_reduce, on by
// default); the reference is the full decode box-filtered (jpeg_reduce off). A 4:2:0 photo-like
// image (ramps, a soft blob, a fine stripe of 10 px period) whose sides (131 x 93) are not multiples
// of 8, so the last partial block is cropped: a reduced decode off by one pixel in place or size
// would differ by tens of levels at the ramps' and stripes' edges, far above the bounds.
TEST(Captures, JpegLoadedReducedMatchesTheBoxFilterOfTheFullDecode) {
  test::TempDir t;
  const int sw = 131, sh = 93;
  std::vector<uint8_t> px(static_cast<size_t>(sw * sh * 3));
  for (int y = 0; y < sh; ++y)
    for (int x = 0; x < sw; ++x) {
      const double blob = std::exp(-((x - 60.0) * (x - 60.0) + (y - 40.0) * (y - 40.0)) / 300.0);
      const double stripe = 0.5 + 0.5 * std::sin(2 * M_PI * x / 10.0);
      const double v[3] = {20 + 1.2 * x + 60 * blob, 200 - 1.5 * y + 30 * stripe, 60 + 150 * blob};
      for (int ch = 0; ch < 3; ++ch)
        px[static_cast<size_t>((y * sw + x) * 3 + ch)] = static_cast<uint8_t>(std::clamp(v[ch], 0.0, 255.0));
    }
  test::JpegOptions jo;
  jo.luma_h = 2, jo.luma_v = 2;
  fs::create_directories(t / "images");
  for (int i = 0; i < 3; ++i)
    test::write_file(t / ("images/p" + std::to_string(i) + ".jpg"), test::encode_jpeg(px, sw, sh, jo));
  test::write_file(
      t / "transforms.json",
      "{\"fl_x\": 100, \"w\": 131, \"h\": 93, \"frames\": ["
      "{\"file_path\": \"images/p0.jpg\", \"transform_matrix\": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]},"
      "{\"file_path\": \"images/p1.jpg\", \"transform_matrix\": [[1,0,0,1],[0,1,0,0],[0,0,1,0],[0,0,0,1]]},"
      "{\"file_path\": \"images/p2.jpg\", \"transform_matrix\": [[1,0,0,0],[0,1,0,1],[0,0,1,0],[0,0,0,1]]}]}");
  // Bounds in levels of 255. Measured with libjpeg-turbo 2.1, largest / mean difference: 1/2
  // 3.0 / 0.88, 1/4 2.9 / 0.77, 1/8 2.3 / 0.53, 1/16 (1/8 in libjpeg, then a 2x2 box) 1.1 / 0.39;
  // the same load with every image shifted by one pixel differs by 16 to 67 / 2.2 to 14. The
  // reduced IDCT keeps the lowest coefficients of each 8x8 block (4x4 for 1/2, 2x2 for 1/4, the DC,
  // the block's mean, for 1/8) where the box filter averages pixels, and it works on the 4:2:0
  // chroma before upsampling: a few levels apart at the stripe and the blob's edges.
  struct Case {
    int f;
    double max_err, max_mean;
  };
  for (const Case& k : {Case{2, 5, 1.2}, Case{4, 5, 1.0}, Case{8, 4, 0.75}, Case{16, 3, 0.6}}) {
    SCOPED_TRACE("downscale " + std::to_string(k.f));
    LoadOptions fast, full;
    fast.downscale = full.downscale = k.f;
    full.jpeg_reduce = false;
    const auto a = Dataset::load(t.path(), fast).split("train").images;
    const auto b = Dataset::load(t.path(), full).split("train").images;
    ASSERT_EQ(a.sizes(), b.sizes());
    EXPECT_EQ(a.size(1), sh / k.f);
    EXPECT_EQ(a.size(2), sw / k.f);
    const auto d = (a - b).abs() * 255;
    EXPECT_LE(d.max().item<double>(), k.max_err);
    EXPECT_LE(d.mean().item<double>(), k.max_mean);
    // The viewer's one-frame read is the loader's image (train's first frame is p1).
    const Capture js = read_capture(t.path(), {}, k.f);
    const auto rgba = frame_photo_rgba(js.splits.front().frames.front(), js.height, js.width, k.f);
    EXPECT_TRUE(torch::equal(rgba.slice(2, 0, 3), a[0]));
  }
}

// A mask image: white (255) in columns [0, white_cols), black elsewhere.
void write_mask(const std::string& path, int w, int h, int white_cols) {
  fs::create_directories(fs::path(path).parent_path());
  auto m = torch::zeros({h, w, 1}, torch::kUInt8);
  m.slice(1, 0, white_cols).fill_(255);
  write_png(path, m);
}

// The masks of a capture (Split::mask): a masks/ folder beside LLFF (and COLMAP) images keeps
// white; the loaded mask keeps a pixel when at least half of its box is kept; data.masks none and
// alpha; a missing, wrongly sized or unreadable mask refused naming the file.
TEST(Captures, MasksFolderKeepsWhitePixelsAtEveryDownscale) {
  test::TempDir t;
  const int W = 16, H = 12;
  const auto frames = ring(10, kTarget, kUp);
  write_llff_npy(t.path(), frames, {H, W, 20.0}, [](size_t) { return std::make_pair(3.0, 5.0); });
  for (size_t i = 0; i < frames.size(); ++i) {
    const std::string stem = "IMG_" + std::to_string(100 + i);
    write_image(t / ("images/" + stem + ".png"), W, H, 100);
    // 7 white columns; IMG_103 all white.
    write_mask(t / ("masks/" + stem + ".png"), W, H, i == 3 ? W : 7);
  }
  LoadOptions o;
  o.scene = SceneKind::Bounded;
  EXPECT_FALSE(Dataset::load(t.path(), o).split("train").mask.defined());  // data.masks = none by default
  o.masks = MaskSource::Auto;
  for (const int down : {1, 2}) {
    SCOPED_TRACE("downscale " + std::to_string(down));
    o.downscale = down;
    const Dataset ds = Dataset::load(t.path(), o);
    const Split& train = ds.split("train");  // IMG_101 ... IMG_107, IMG_109
    ASSERT_TRUE(train.mask.defined());
    ASSERT_EQ(train.mask.sizes(), (std::vector<int64_t>{8, H / down, W / down}));
    // Downscale 2: the box of columns 6-7 is half white, so loaded column 3 is kept, column 4 not.
    const int keep_cols = down == 1 ? 7 : 4;
    for (int64_t i = 0; i < train.size(); ++i) {
      auto want = torch::zeros({H / down, W / down}, torch::kBool);
      want.slice(1, 0, name_of(train, i) == "IMG_103.png" ? W / down : keep_cols).fill_(true);
      EXPECT_TRUE(torch::equal(train.mask[i], want)) << name_of(train, i);
    }
    EXPECT_TRUE(ds.split("test").mask.defined());  // eval scores the kept part too
  }
  o.downscale = 1;
  o.masks = MaskSource::None;
  EXPECT_FALSE(Dataset::load(t.path(), o).split("train").mask.defined());
  o.masks = MaskSource::Alpha;  // opaque photos: every pixel kept
  const auto alpha_mask = Dataset::load(t.path(), o).split("train").mask;
  ASSERT_TRUE(alpha_mask.defined());
  EXPECT_TRUE(alpha_mask.all().item<bool>());
  o.masks = MaskSource::Auto;
  const std::string bad = (t / "masks/IMG_103.png");
  write_mask(bad, W / 2, H / 2, 3);
  test::expect_input_error([&] { Dataset::load(t.path(), o); }, fs::canonical(bad).string(), "masks/", "mask is 8x6",
                           true);
  test::write_file(bad, "not an image");
  test::expect_input_error([&] { Dataset::load(t.path(), o); }, fs::canonical(bad).string(), "", "not a PNG or JPEG",
                           true);
  fs::remove(bad);
  // NeRD's naming, the stem and "_mask": found when the stem alone is not there.
  write_mask(t / "masks/IMG_103_mask.png", W, H, 2);
  {
    const Dataset named = Dataset::load(t.path(), o);
    const Split& train = named.split("train");
    bool seen = false;
    for (int64_t i = 0; i < train.size(); ++i)
      if (name_of(train, i) == "IMG_103.png") {
        EXPECT_EQ(train.mask[i].sum().item<int64_t>(), 2 * H);
        seen = true;
      }
    EXPECT_TRUE(seen);
  }
  fs::remove(t / "masks/IMG_103_mask.png");
  test::expect_input_error([&] { Dataset::load(t.path(), o); }, fs::canonical(t / "masks").string(),
                           "row 3 (IMG_103.png)", "no mask for images/IMG_103.png", true);
}

// transforms.json masks: nerfstudio's per-frame mask_path keeps white; instant-ngp's
// dynamic_mask_<stem>.png beside the image marks the pixels to leave out; a frame without either
// keeps every pixel.
TEST(Captures, MaskPathAndInstantNgpDynamicMasks) {
  test::TempDir t;
  const int W = 12, H = 8;
  for (int i = 0; i < 3; ++i) write_image(t / ("images/p" + std::to_string(i) + ".png"), W, H, 80);
  write_mask(t / "mask0.png", W, H, 5);                   // frame 0 (test): keeps columns 0-4
  write_mask(t / "images/dynamic_mask_p1.png", W, H, 3);  // frame 1: columns 0-2 are a moving object
  const auto json_with = [&](const std::string& mask0) {
    return "{\"fl_x\": 10, \"w\": 12, \"h\": 8, \"frames\": ["
           "{\"file_path\": \"images/p0.png\", \"mask_path\": \"" +
           mask0 +
           "\", \"transform_matrix\": "
           "[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]},"
           "{\"file_path\": \"images/p1.png\", \"transform_matrix\": [[1,0,0,1],[0,1,0,0],[0,0,1,0],[0,0,0,1]]},"
           "{\"file_path\": \"images/p2.png\", \"transform_matrix\": [[1,0,0,0],[0,1,0,1],[0,0,1,0],[0,0,0,1]]}]}";
  };
  test::write_file(t / "transforms.json", json_with("mask0.png"));
  LoadOptions o;
  o.masks = MaskSource::Auto;
  const Dataset ds = Dataset::load(t.path(), o);
  const auto& train = ds.split("train").mask;  // p1, p2
  ASSERT_TRUE(train.defined());
  EXPECT_FALSE(train[0].slice(1, 0, 3).any().item<bool>());
  EXPECT_TRUE(train[0].slice(1, 3, W).all().item<bool>());
  EXPECT_TRUE(train[1].all().item<bool>());
  const auto& test_mask = ds.split("test").mask;  // p0
  ASSERT_TRUE(test_mask.defined());
  EXPECT_TRUE(test_mask[0].slice(1, 0, 5).all().item<bool>());
  EXPECT_FALSE(test_mask[0].slice(1, 5, W).any().item<bool>());
  test::write_file(t / "transforms.json", json_with("missing.png"));
  test::expect_input_error([&] { Dataset::load(t.path(), o); }, t / "transforms.json", "frames[0].mask_path",
                           "image not found", true);
}

// The real captures of docs/CAPTURES.md, when they sit in captures/ under the checkout (where its
// recipes put them) or beside it: each loads, in its format, with the frame counts and bounds source
// the document records.
TEST(Captures, RealCapturesWhenPresent) {
  const fs::path inside = fs::path(test::source_dir()) / "captures";
  const fs::path base = fs::is_directory(inside) ? inside : fs::path(test::source_dir()).parent_path() / "captures";
  struct Want {
    const char* dir;
    const char* format;
    int64_t frames;
    int downscale;
    const char* bounds;
    SceneKind kind = SceneKind::Unbounded;
    int64_t width = 0;  // the images' width as read, when checked
  };
  const Want wants[] = {{"fox50", "instant-ngp", 50, 8, "cameras"},
                        {"fox_colmap", "colmap", 67, 2, "points"},
                        {"fox_colmap_txt", "colmap", 67, 2, "points"},
                        {"fox_ns", "nerfstudio", 67, 2, "points"},
                        {"ethiopianhead_llff", "llff", 66, 8, "llff bounds"},
                        {"fern_llff", "llff", 20, 8, "llff bounds", SceneKind::ForwardFacing, 504},
                        // LLFF's 1/8 copies alone (no images/): read as they are, not reduced again.
                        {"horns_llff", "llff", 62, 8, "llff bounds", SceneKind::ForwardFacing, 504}};
  int found = 0;
  for (const Want& w : wants) {
    const fs::path dir = base / w.dir;
    if (!fs::is_directory(dir)) continue;
    ++found;
    SCOPED_TRACE(w.dir);
    LoadOptions o;
    o.downscale = w.downscale;
    const Dataset ds = Dataset::load(dir.string(), o);
    EXPECT_EQ(ds.format, w.format);
    EXPECT_EQ(ds.split("train").size() + ds.split("test").size(), w.frames);
    EXPECT_EQ(ds.split("test").size(), (w.frames + 7) / 8);
    EXPECT_EQ(ds.scene.bounds_source, w.bounds);
    EXPECT_EQ(ds.scene.kind, w.kind);
    if (w.kind == SceneKind::Unbounded) {  // every camera inside the unit sphere, the farthest on it
      const auto c = torch::cat({ds.split("train").c2w, ds.split("test").c2w}).select(2, 3).norm(2, 1);
      EXPECT_NEAR(c.max().item<double>(), 1.0, 1e-5);
    }
    if (w.width > 0) {
      EXPECT_EQ(ds.split("train").images.size(2), w.width);
    }
    // Real photos: neither blank nor saturated.
    const double mean = ds.split("train").images.mean().item<double>();
    EXPECT_GT(mean, 0.1);
    EXPECT_LT(mean, 0.9);
  }
  if (found == 0) GTEST_SKIP() << base << " holds none of the captures of docs/CAPTURES.md";
}
