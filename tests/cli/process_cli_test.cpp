// `ablenerf process`: photos without poses -> a COLMAP capture. Refusals always run (a fake COLMAP
// stands in where one is needed); the real pipeline runs when Debian's `colmap` is installed
// (scripts/test.sh installs it), on photos this test renders itself of a textured box corner from
// known cameras, and the recovered camera centres are compared with the true ones.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <random>
#include <nlohmann/json.hpp>
#include <sys/stat.h>

#include "data/colmap_model.h"
#include "data/colmap_process.h"
#include "data/dataset.h"
#include "test_geometry.h"
#include "test_util.h"
#include "util/image_io.h"
#include "util/subprocess.h"

using namespace ablenerf;
namespace fs = std::filesystem;

namespace {

// Three planes x = 0, y = 0, z = 0 (0..kSide on the other two axes), each with its own smooth random
// colour texture (three octaves of bilinear value noise): features for SIFT that do not repeat.
constexpr double kSide = 2.5;

struct Texture {
  std::vector<std::vector<float>> octaves;  // (g+1)^2 x 3 values per octave
  std::vector<int> grids{8, 24, 64};
  explicit Texture(uint32_t seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    for (int g : grids) {
      std::vector<float> v(static_cast<size_t>((g + 1) * (g + 1) * 3));
      for (auto& x : v) x = u(rng);
      octaves.push_back(std::move(v));
    }
  }
  std::array<float, 3> at(double s, double t) const {
    const double weights[3] = {0.5, 0.3, 0.2};
    std::array<float, 3> c{0, 0, 0};
    for (size_t o = 0; o < grids.size(); ++o) {
      const int g = grids[o];
      const double x = std::clamp(s, 0.0, 1.0) * g, y = std::clamp(t, 0.0, 1.0) * g;
      const int x0 = std::min(static_cast<int>(x), g - 1), y0 = std::min(static_cast<int>(y), g - 1);
      const double fx = x - x0, fy = y - y0;
      const auto& v = octaves[o];
      const auto val = [&](int xx, int yy, int ch) { return v[static_cast<size_t>((yy * (g + 1) + xx) * 3 + ch)]; };
      for (int ch = 0; ch < 3; ++ch)
        c[static_cast<size_t>(ch)] += static_cast<float>(
            weights[o] * (val(x0, y0, ch) * (1 - fx) * (1 - fy) + val(x0 + 1, y0, ch) * fx * (1 - fy) +
                          val(x0, y0 + 1, ch) * (1 - fx) * fy + val(x0 + 1, y0 + 1, ch) * fx * fy));
    }
    return c;
  }
};

// `n` photos (w x h, focal f) from cameras 6 units away on an arc of azimuth 20..70 degrees at
// elevation 35, looking at (0.8, 0.8, 0.6). Returns the camera centres.
std::vector<test::V3> render_corner(const std::string& dir, int n, int w, int h, double f) {
  const Texture tex[3] = {Texture(1), Texture(2), Texture(3)};
  fs::create_directories(dir);
  std::vector<test::V3> eyes;
  for (int k = 0; k < n; ++k) {
    const double az = (20.0 + 50.0 * k / (n - 1)) * M_PI / 180, el = 35.0 * M_PI / 180;
    const test::V3 eye{6 * std::cos(el) * std::cos(az), 6 * std::cos(el) * std::sin(az), 6 * std::sin(el)};
    const test::Frame3 cam = test::look_at(eye, {0.8, 0.8, 0.6}, {0, 0, 1});
    auto img = torch::full({h, w, 3}, 0.5f);
    auto a = img.accessor<float, 3>();
    for (int j = 0; j < h; ++j)
      for (int i = 0; i < w; ++i) {
        const double x = (i + 0.5 - w / 2.0) / f, y = -(j + 0.5 - h / 2.0) / f;
        test::V3 d;
        for (size_t c = 0; c < 3; ++c) d[c] = x * cam.right[c] + y * cam.up[c] - cam.back[c];
        double best = 1e30;
        for (size_t axis = 0; axis < 3; ++axis) {
          const double t = -eye[axis] / d[axis];
          if (!(t > 0) || t >= best) continue;
          const size_t p = (axis + 1) % 3, q = (axis + 2) % 3;
          const double u = eye[p] + t * d[p], v = eye[q] + t * d[q];
          if (u < 0 || u > kSide || v < 0 || v > kSide) continue;
          best = t;
          const auto c = tex[axis].at(u / kSide, v / kSide);
          for (int ch = 0; ch < 3; ++ch) a[j][i][ch] = c[static_cast<size_t>(ch)];
        }
      }
    char name[32];
    std::snprintf(name, sizeof(name), "/v%02d.png", k);
    write_png(dir + name, img);
    eyes.push_back(eye);
  }
  return eyes;
}

// A stand-in for COLMAP: a shell script that fails at `fail_at` (or nowhere) and writes nothing.
std::string fake_colmap(const std::string& dir, const std::string& fail_at) {
  const std::string path = dir + "/fake_colmap";
  test::write_file(path, "#!/bin/sh\necho \"fake colmap $1\"\n[ \"$1\" = \"" + fail_at + "\" ] && exit 3\nexit 0\n");
  ::chmod(path.c_str(), 0755);
  return path;
}

int lines(const std::string& s) { return static_cast<int>(std::count(s.begin(), s.end(), '\n')); }

// A small grey PNG.
void photo(const std::string& path, int w, int h) {
  fs::create_directories(fs::path(path).parent_path());
  write_png(path, torch::full({h, w, 3}, 0.5f));
}

TEST(Process, RefusesBadInputWithOneLine) {
  test::TempDir t;
  fs::create_directories(t / "empty");
  photo(t / "photos/a.png", 8, 6);
  photo(t / "mixed/a.png", 8, 6);
  photo(t / "mixed/b.png", 6, 8);
  photo(t / "mixed/c.png", 8, 6);
  test::write_file(t / "iphone/IMG_0001.HEIC", "heic bytes");
  test::write_file(t / "iphone/IMG_0002.HEIC", "heic bytes");
  photo(t / "broken/a.png", 8, 6);
  test::write_file(t / "broken/b.jpg", "not really a photo");
  test::write_file(t / "taken/keep.txt", "a user's file");
  const std::string fake = fake_colmap(t.path(), "none");
  struct Case {
    std::string args, expect;
    int code;
  };
  const std::vector<Case> cases{
      {"--out " + t / "o1", "give exactly one of them", 2},
      {"--images " + t / "photos" + " --video x.mp4 --out " + t / "o1", "give exactly one of them", 2},
      {"--images " + t / "missing" + " --out " + t / "o1", "--images: not a folder", 2},
      {"--images " + t / "empty" + " --out " + t / "o1" + " --colmap " + fake, "no JPEG or PNG photos", 2},
      {"--images " + t / "photos" + " --out " + t / "o1" + " --camera-model FOV", "--camera-model", 2},
      {"--images " + t / "photos" + " --out " + t / "o1" + " --matcher vocab", "--matcher", 2},
      {"--images " + t / "photos" + " --out " + t / "taken", "exists and is not an empty folder", 2},
      {"--images " + t / "mixed" + " --out " + t / "o1" + " --colmap " + fake,
       "b.png: size: 6x8 but 2 of the 3 photos are 8x6", 2},
      {"--images " + t / "broken" + " --out " + t / "o1" + " --colmap " + fake, "b.jpg", 2},
      {"--images " + t / "iphone" + " --out " + t / "o1" + " --colmap " + fake,
       "no JPEG or PNG photos in this folder; 2 other images (IMG_0001.HEIC, ...) are not read: convert to JPEG", 2},
      {"--images " + t / "photos" + " --out " + t / "o1" + " --colmap " + t / "no_colmap", "apt-get install colmap", 1},
  };
  for (const auto& c : cases) {
    const auto r = test::run_cli("process " + c.args);
    EXPECT_EQ(r.exit_code, c.code) << c.args << "\n" << r.output;
    EXPECT_NE(r.output.find(c.expect), std::string::npos) << c.args << "\n" << r.output;
    EXPECT_EQ(lines(r.output), 1) << c.args << "\n" << r.output;
  }
  EXPECT_EQ(read_file(t / "taken/keep.txt"), "a user's file");  // nothing already there is touched
  EXPECT_FALSE(fs::exists(t / "o1"));                           // no capture folder is left behind by a refusal
}

TEST(Process, ColmapFailuresNameTheLog) {
  test::TempDir t;
  photo(t / "photos/a.png", 8, 6);
  photo(t / "photos/b.png", 8, 6);
  test::write_file(t / "photos/notes.txt", "x");
  test::write_file(t / "photos/c.heic", "x");
  // The mapper fails: the line names the log and the stage; the log holds COLMAP's own output.
  auto r = test::run_cli("process --images " + t / "photos" + " --out " + t / "a --colmap " +
                         fake_colmap(t.path(), "mapper"));
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find(t / "a/colmap.log"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("mapper: failed with exit status 3"), std::string::npos) << r.output;
  EXPECT_NE(read_file(t / "a/colmap.log").find("fake colmap feature_extractor"), std::string::npos);
  EXPECT_TRUE(fs::exists(t / "a/images/a.png") && fs::exists(t / "a/images/b.png"));
  EXPECT_FALSE(fs::exists(t / "a/images/notes.txt"));
  EXPECT_FALSE(fs::exists(t / "a/images/c.heic"));
  EXPECT_NE(r.output.find("note: 1 other image (c.heic) is not read"), std::string::npos) << r.output;
  // Every stage succeeds but no model comes out: too few images placed.
  r = test::run_cli("process --images " + t / "photos" + " --out " + t / "b --colmap " + fake_colmap(t.path(), "none"));
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("placed 0 of 2 images"), std::string::npos) << r.output;
}

TEST(Process, CommandLines) {
  ProcessOptions o;
  o.threads = 3;
  auto c = colmap_commands(o, "/cap", 40);
  ASSERT_EQ(c.size(), 3u);
  EXPECT_EQ(c[0][1], "feature_extractor");
  EXPECT_NE(std::find(c[0].begin(), c[0].end(), "OPENCV"), c[0].end());
  EXPECT_NE(std::find(c[0].begin(), c[0].end(), "/cap/images"), c[0].end());
  EXPECT_EQ(c[1][1], "exhaustive_matcher");
  EXPECT_EQ(c[2][1], "mapper");
  EXPECT_NE(std::find(c[2].begin(), c[2].end(), "/cap/sparse"), c[2].end());
  EXPECT_EQ(c[2].back(), "3");
  EXPECT_EQ(colmap_commands(o, "/cap", kExhaustiveMaxImages + 1)[1][1], "sequential_matcher");
  o.video = "walk.mp4";  // a video's frames: neighbours only, however few
  EXPECT_EQ(colmap_commands(o, "/cap", 10)[1][1], "sequential_matcher");
  o.matcher = "exhaustive";
  EXPECT_EQ(colmap_commands(o, "/cap", 10)[1][1], "exhaustive_matcher");
  o.video.clear();
  o.matcher = "sequential";
  EXPECT_EQ(colmap_commands(o, "/cap", 10)[1][1], "sequential_matcher");
}

// Rotation, translation and scale that best map `a` onto `b` (Umeyama); returns the largest
// distance between the mapped a_i and b_i.
double aligned_max_error(const std::vector<test::V3>& a, const std::vector<test::V3>& b) {
  auto A = torch::empty({static_cast<int64_t>(a.size()), 3}, torch::kFloat64), B = torch::empty_like(A);
  for (size_t i = 0; i < a.size(); ++i)
    for (size_t c = 0; c < 3; ++c) {
      A[static_cast<int64_t>(i)][static_cast<int64_t>(c)] = a[i][c];
      B[static_cast<int64_t>(i)][static_cast<int64_t>(c)] = b[i][c];
    }
  const auto ma = A.mean(0), mb = B.mean(0);
  const auto Ac = A - ma, Bc = B - mb;
  const auto svd = torch::linalg_svd(Bc.t().mm(Ac), false);
  auto U = std::get<0>(svd), S = std::get<1>(svd), Vh = std::get<2>(svd);
  auto D = torch::ones({3}, torch::kFloat64);
  if ((torch::det(U) * torch::det(Vh)).item<double>() < 0) D[2] = -1;
  const auto R = U.mm(torch::diag(D)).mm(Vh);
  const double s = (S * D).sum().item<double>() / Ac.pow(2).sum().item<double>();
  const auto mapped = s * Ac.mm(R.t()) + mb;
  return (mapped - B).norm(2, 1).max().item<double>();
}

// A COLMAP image's camera centre, C = -R^T t with R the world-to-camera rotation of its quaternion.
test::V3 centre(const ColmapImage& im) {
  const double w = im.qvec[0], x = im.qvec[1], y = im.qvec[2], z = im.qvec[3];
  const double R[3][3] = {{1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)},
                          {2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)},
                          {2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)}};
  test::V3 c{};
  for (size_t a = 0; a < 3; ++a)
    for (size_t b = 0; b < 3; ++b) c[a] -= R[b][a] * im.tvec[b];
  return c;
}

TEST(Process, RecoversTheCamerasOfRenderedPhotos) {
  if (!program_available("colmap")) GTEST_SKIP() << "colmap not installed (Debian: apt-get install colmap)";
  test::TempDir t;
  const int n = 20;
  const auto eyes = render_corner(t / "photos", n, 320, 240, 280.0);
  const auto r = test::run_cli("process --images " + t / "photos" + " --out " + t / "cap" + " --threads 2");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto j = nlohmann::json::parse(r.output.substr(r.output.find('{')));
  EXPECT_EQ(j["registered"], n);
  EXPECT_GT(j["points"].get<int>(), 500);
  // The next command names the capture preset, not a file of the checkout; no note of photos left out.
  EXPECT_EQ(j["next"], "ablenerf train --data " + t / "cap" + " --preset capture --out runs/NAME");
  EXPECT_EQ(r.output.find("note: COLMAP placed"), std::string::npos) << r.output;
  // COLMAP's camera centres (C = -R^T t) against the true ones, after the best similarity: the
  // reconstruction is only defined up to one.
  const ColmapModel m = read_colmap_model(t / "cap/sparse/0");
  ASSERT_EQ(m.images.size(), static_cast<size_t>(n));
  std::vector<test::V3> got, want;
  for (const auto& im : m.images) {
    got.push_back(centre(im));
    want.push_back(eyes[static_cast<size_t>(std::stoi(im.name.substr(1, 2)))]);
  }
  EXPECT_LT(aligned_max_error(got, want), 0.01);  // cameras 6 units away, 5 apart at the arc's ends (measured 0.002)
  // The focal COLMAP found is the renderer's (280 pixels), within 2%.
  EXPECT_NEAR(m.cameras.front().params[0], 280.0, 5.6);  // measured 277.1
  // And the capture loads as one: every photo, COLMAP's lens.
  const Dataset ds = Dataset::load(t / "cap");
  EXPECT_EQ(ds.format, "colmap");
  int64_t frames = 0;
  for (const auto& [name, split] : ds.splits) frames += split.size();
  EXPECT_EQ(frames, n);
}

// A video of the same photos (H.264 by ffmpeg), sampled to 10 of its 20 frames: every other photo.
TEST(Process, VideoFramesAreSampledAndPlaced) {
  if (!program_available("colmap") || !program_available("ffmpeg")) GTEST_SKIP() << "colmap or ffmpeg not installed";
  test::TempDir t;
  const auto eyes = render_corner(t / "photos", 20, 320, 240, 280.0);
  ASSERT_EQ(run_logged({"ffmpeg", "-hide_banner", "-framerate", "10", "-i", t / "photos/v%02d.png", "-c:v", "libx264",
                        "-pix_fmt", "yuv420p", t / "corner.mp4"},
                       t / "ffmpeg.log"),
            0)
      << read_file(t / "ffmpeg.log");
  const auto r = test::run_cli("process --video " + t / "corner.mp4" + " --frames 10 --out " + t / "cap --threads 2");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("every 2 of 20 frames"), std::string::npos) << r.output;
  const ColmapModel m = read_colmap_model(t / "cap/sparse/0");
  ASSERT_EQ(m.images.size(), 10u);
  std::vector<test::V3> got, want;
  for (const auto& im : m.images) {  // frame_0000K.jpg is photo 2 (K - 1)
    got.push_back(centre(im));
    want.push_back(eyes[static_cast<size_t>(2 * (std::stoi(im.name.substr(6, 5)) - 1))]);
  }
  EXPECT_LT(aligned_max_error(got, want), 0.02);
}

}  // namespace
