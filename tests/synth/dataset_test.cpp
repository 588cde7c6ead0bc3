// The written demo dataset, checked through its files against independent references:
// analytic ray-sphere depth, projected sphere centres, the Blender loader, determinism.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>

#include "data/dataset.h"
#include "synth/scene.h"
#include "synth_test_util.h"
#include "test_util.h"
#include "util/errors.h"
#include "util/fs.h"
#include "util/image_io.h"

using namespace ablenerf;
using namespace ablenerf::synth_test;
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

constexpr int kRes = 40;
constexpr int kTrain = 6, kTest = 4;

struct SphereRef {
  std::string material;
  V3 centre;
  double radius;
};

json read_json(const std::string& path) { return json::parse(read_file(path)); }

std::vector<SphereRef> spheres_from_scene_json(const std::string& dir) {
  std::vector<SphereRef> out;
  const json scene = read_json(dir + "/scene.json");
  for (const auto& o : scene.at("objects")) {
    const auto& c = o.at("centre");
    out.push_back({o.at("material").get<std::string>(),
                   {c[0].get<double>(), c[1].get<double>(), c[2].get<double>()},
                   o.at("radius").get<double>()});
  }
  return out;
}

std::string file_bytes(const std::string& path) { return read_file(path); }

// One small dataset shared by the tests of this file (rendering it takes well under a second).
class SynthDataset : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    tmp_ = std::make_unique<test::TempDir>("synth_ds");
    SynthOptions o;
    o.res = kRes;
    o.train_views = kTrain;
    o.test_views = kTest;
    o.seed = 7;
    o.progress = [](int done, int total) {
      ++progress_calls_;
      last_done_ = done;
      last_total_ = total;
    };
    write_synthetic_dataset(tmp_->path(), o);
  }
  static void TearDownTestSuite() { tmp_.reset(); }
  static std::string dir() { return tmp_->path(); }

  static std::unique_ptr<test::TempDir> tmp_;
  static int progress_calls_, last_done_, last_total_;
};
std::unique_ptr<test::TempDir> SynthDataset::tmp_;
int SynthDataset::progress_calls_ = 0, SynthDataset::last_done_ = 0, SynthDataset::last_total_ = 0;

TEST_F(SynthDataset, WritesBlenderLayoutAndReportsProgress) {
  for (int k = 0; k < kTrain; ++k) EXPECT_TRUE(fs::exists(dir() + "/train/r_" + std::to_string(k) + ".png"));
  for (int k = 0; k < kTest; ++k) {
    const std::string base = dir() + "/test/r_" + std::to_string(k);
    EXPECT_TRUE(fs::exists(base + ".png"));
    EXPECT_TRUE(fs::exists(base + "_depth.pt"));
    EXPECT_TRUE(fs::exists(base + "_depth.png"));
  }
  const json tr = read_json(dir() + "/transforms_train.json");
  EXPECT_DOUBLE_EQ(tr.at("camera_angle_x").get<double>(), 0.6911112);
  ASSERT_EQ(tr.at("frames").size(), static_cast<size_t>(kTrain));
  EXPECT_EQ(tr.at("frames")[2].at("file_path"), "./train/r_2");  // Blender style: no extension
  const json te = read_json(dir() + "/transforms_test.json");
  EXPECT_EQ(te.at("frames")[1].at("depth_file_path"), "./test/r_1_depth.pt");
  const json scene = read_json(dir() + "/scene.json");
  EXPECT_EQ(scene.at("seed").get<int>(), 7);
  EXPECT_EQ(scene.at("objects").size(), 3u);
  // RGBA 8-bit PNGs of the requested size.
  const auto im = read_png(dir() + "/train/r_0.png");
  EXPECT_EQ(im.size(0), kRes);
  EXPECT_EQ(im.size(1), kRes);
  EXPECT_EQ(im.size(2), 4);
  EXPECT_EQ(progress_calls_, kTrain + kTest);
  EXPECT_EQ(last_done_, kTrain + kTest);
  EXPECT_EQ(last_total_, kTrain + kTest);
}

TEST_F(SynthDataset, TestDepthMatchesAnalyticRaySphereDistance) {
  const auto spheres = spheres_from_scene_json(dir());
  ASSERT_EQ(spheres.size(), 3u);
  const json te = read_json(dir() + "/transforms_test.json");
  for (int k = 0; k < kTest; ++k) {
    const std::string bytes = read_file(dir() + "/test/r_" + std::to_string(k) + "_depth.pt");
    const auto depth = torch::pickle_load(std::vector<char>(bytes.begin(), bytes.end())).toTensor();
    ASSERT_EQ(depth.scalar_type(), torch::kFloat);
    ASSERT_EQ(depth.dim(), 2);
    ASSERT_EQ(depth.size(0), kRes);
    ASSERT_EQ(depth.size(1), kRes);
    const auto acc = depth.accessor<float, 2>();
    const JsonCamera cam = camera_from_json(te, static_cast<size_t>(k), kRes, kRes);
    std::vector<int> hits_per_sphere(spheres.size(), 0);
    int misses = 0;
    for (int j = 0; j < kRes; ++j)
      for (int i = 0; i < kRes; ++i) {
        const V3 d = cam.dir(i + 0.5, j + 0.5);
        double best = -1;
        int which = -1;
        for (size_t s = 0; s < spheres.size(); ++s) {
          const double t = ray_sphere(cam.origin(), d, spheres[s].centre, spheres[s].radius);
          if (t > 0 && (best < 0 || t < best)) {
            best = t;
            which = static_cast<int>(s);
          }
        }
        if (which < 0) {
          EXPECT_EQ(acc[j][i], 0.0f) << "view " << k << " pixel " << i << "," << j;
          ++misses;
        } else {
          // float32 storage of a depth near 4: a few 1e-7 relative.
          EXPECT_NEAR(acc[j][i], best, 2e-5) << "view " << k << " pixel " << i << "," << j;
          ++hits_per_sphere[static_cast<size_t>(which)];
        }
      }
    // The test orbit sees every object and plenty of background.
    for (size_t s = 0; s < spheres.size(); ++s) EXPECT_GT(hits_per_sphere[s], 20) << "view " << k << " sphere " << s;
    EXPECT_GT(misses, kRes * kRes / 3);
  }
}

TEST_F(SynthDataset, AlphaIsZeroOnBackgroundAndOneOnObjects) {
  const auto spheres = spheres_from_scene_json(dir());
  const json te = read_json(dir() + "/transforms_test.json");
  for (int k = 0; k < kTest; ++k) {
    const auto im = read_png(dir() + "/test/r_" + std::to_string(k) + ".png");
    const auto a = im.accessor<uint8_t, 3>();
    for (int y : {0, kRes - 1})
      for (int x : {0, kRes - 1}) EXPECT_EQ(a[y][x][3], 0) << "corner " << x << "," << y;
    const JsonCamera cam = camera_from_json(te, static_cast<size_t>(k), kRes, kRes);
    for (const auto& s : spheres) {
      double px, py;
      ASSERT_TRUE(cam.project(s.centre, px, py));
      EXPECT_EQ(a[static_cast<int>(py)][static_cast<int>(px)][3], 255) << s.material << " centre, view " << k;
    }
    // Every pixel whose whole footprint clearly misses (or lies inside) a sphere's silhouette.
    int bg = 0, fg = 0;
    for (int j = 0; j < kRes; ++j)
      for (int i = 0; i < kRes; ++i) {
        const V3 d = cam.dir(i + 0.5, j + 0.5);
        const double dn = std::sqrt(dot3(d, d));
        bool clear_miss = true, clear_hit = false;
        for (const auto& s : spheres) {
          const V3 oc = sub(s.centre, cam.origin());
          const double along = dot3(oc, d) / dn;
          const double dist = std::sqrt(std::max(0.0, dot3(oc, oc) - along * along));  // ray-centre distance
          const double margin = std::sqrt(dot3(oc, oc)) / cam.focal;                   // > half a pixel diagonal there
          if (dist < s.radius + margin) clear_miss = false;
          if (dist < s.radius - margin) clear_hit = true;
        }
        if (clear_miss) {
          EXPECT_EQ(a[j][i][3], 0) << i << "," << j;
          EXPECT_EQ(a[j][i][0], 0);
          ++bg;
        }
        if (clear_hit) {
          EXPECT_EQ(a[j][i][3], 255) << i << "," << j;
          ++fg;
        }
      }
    EXPECT_GT(bg, 100);
    EXPECT_GT(fg, 100);
  }
}

TEST_F(SynthDataset, LoadsWithTheBlenderLoaderAndPosesAreOnTheUpperHemisphere) {
  const Dataset ds = Dataset::load(dir());
  EXPECT_EQ(ds.format, "blender");
  ASSERT_TRUE(ds.has("train"));
  ASSERT_TRUE(ds.has("test"));
  EXPECT_EQ(ds.split("train").size(), kTrain);
  EXPECT_EQ(ds.split("test").size(), kTest);
  EXPECT_EQ(ds.intrinsics.width, kRes);
  EXPECT_EQ(ds.intrinsics.height, kRes);
  EXPECT_NEAR(ds.intrinsics.fx, 0.5 * kRes / std::tan(0.5 * 0.6911112), 1e-9);
  ASSERT_TRUE(ds.split("test").depth.defined());
  EXPECT_EQ(ds.split("test").depth.sizes(), (std::vector<int64_t>{kTest, kRes, kRes}));
  EXPECT_FALSE(ds.split("train").depth.defined());
  for (const char* name : {"train", "test"}) {
    const auto c2w = ds.split(name).c2w.to(torch::kDouble);
    for (int64_t n = 0; n < c2w.size(0); ++n) {
      const auto r = c2w[n].slice(1, 0, 3);
      const auto t = c2w[n].select(1, 3);
      EXPECT_LT((r.t().matmul(r) - torch::eye(3, torch::kDouble)).abs().max().item<double>(), 1e-6);
      EXPECT_NEAR(torch::det(r).item<double>(), 1.0, 1e-6);
      EXPECT_NEAR(t.norm().item<double>(), 4.0, 1e-5);
      const double elev = std::asin(t[2].item<double>() / 4.0) * 180.0 / M_PI;
      EXPECT_GE(elev, 10.0 - 1e-6) << name << " " << n;
      EXPECT_LE(elev, 80.0 + 1e-6) << name << " " << n;
      // Looks at the origin (camera z = backwards = centre direction) with no roll (x horizontal).
      EXPECT_LT((r.select(1, 2) - t / 4.0).abs().max().item<double>(), 1e-6);
      EXPECT_NEAR(r[2][0].item<double>(), 0.0, 1e-6);
      EXPECT_GT(r[2][1].item<double>(), 0.0);  // camera up points upwards
    }
  }
  // Test views: an orbit at 30 degrees elevation.
  const auto tz = ds.split("test").c2w.select(2, 3).select(1, 2);
  EXPECT_LT((tz - 4.0 * std::sin(30.0 * M_PI / 180.0)).abs().max().item<double>(), 1e-5);
  // Composited on white by the loader: alpha-0 pixels become white, so the corners are 1.
  EXPECT_FLOAT_EQ(ds.split("test").images[0][0][0][0].item<float>(), 1.0f);
}

TEST(SynthDeterminism, SameSeedIsByteIdenticalWhateverTheThreadCountAndSeedsDiffer) {
  test::TempDir a("synth_a"), b("synth_b"), c("synth_c");
  SynthOptions o;
  o.res = 16;
  o.train_views = 3;
  o.test_views = 2;
  o.seed = 3;
  o.threads = 1;
  write_synthetic_dataset(a.path(), o);
  o.threads = 3;
  write_synthetic_dataset(b.path(), o);
  o.seed = 4;
  write_synthetic_dataset(c.path(), o);
  std::vector<std::string> files = {"transforms_train.json", "transforms_test.json", "scene.json"};
  for (int k = 0; k < 3; ++k) files.push_back("train/r_" + std::to_string(k) + ".png");
  for (int k = 0; k < 2; ++k) {
    files.push_back("test/r_" + std::to_string(k) + ".png");
    files.push_back("test/r_" + std::to_string(k) + "_depth.pt");
    files.push_back("test/r_" + std::to_string(k) + "_depth.png");
  }
  for (const auto& f : files) EXPECT_EQ(file_bytes(a / f), file_bytes(b / f)) << f;
  // Another seed moves every training camera; the test orbit does not depend on the seed.
  EXPECT_NE(file_bytes(a / "transforms_train.json"), file_bytes(c / "transforms_train.json"));
  for (int k = 0; k < 3; ++k) {
    const std::string f = "train/r_" + std::to_string(k) + ".png";
    EXPECT_NE(file_bytes(a / f), file_bytes(c / f)) << f;
  }
  EXPECT_EQ(file_bytes(a / "test/r_0.png"), file_bytes(c / "test/r_0.png"));
}

TEST(SynthValidation, RejectsTooSmallImagesAndNoViews) {
  SynthOptions o;
  o.res = 4;
  try {
    synth::validate(o);
    FAIL() << "res 4 accepted";
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "--res");
  }
  o.res = 8;
  EXPECT_NO_THROW(synth::validate(o));
  o.train_views = 0;
  EXPECT_THROW(synth::validate(o), InputError);
  o.train_views = 1;
  o.test_views = 0;
  EXPECT_THROW(synth::validate(o), InputError);
}

}  // namespace
