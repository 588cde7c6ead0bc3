// Dataset loader: the real lego scene (when ../shared/data is present), downscaling, compositing,
// the instant-ngp / nerfstudio transforms.json, and every bad-input case of the Blender format.
#include <gtest/gtest.h>
#include <ATen/Parallel.h>
#include <torch/torch.h>

#include <cmath>
#include <filesystem>
#include <fstream>

#include "data/dataset.h"
#include "test_util.h"
#include "util/errors.h"
#include "util/image_io.h"
#include "data/data_config.h"

using namespace ablenerf;
namespace fs = std::filesystem;

namespace {

const char* kIdentityPose = "[[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]";

// A tiny Blender-format scene: `n` RGBA images of w x h with known pixel values.
void make_blender(const std::string& dir, int n, int w, int h, const std::string& pose = kIdentityPose,
                  const std::string& extra_top = "\"camera_angle_x\": 0.6911112070083618") {
  std::string frames;
  for (int i = 0; i < n; ++i) {
    auto img = torch::zeros({h, w, 4}, torch::kUInt8);
    img.select(2, 0).fill_(200);
    img.select(2, 1).fill_(100);
    img.select(2, 2).fill_(50);
    img.select(2, 3).fill_(255);
    fs::create_directories(dir + "/train");
    write_png(dir + "/train/r_" + std::to_string(i) + ".png", img);
    frames += std::string(i ? "," : "") + "{\"file_path\": \"./train/r_" + std::to_string(i) +
              "\", \"transform_matrix\": " + pose + "}";
  }
  test::write_file(dir + "/transforms_train.json", "{" + extra_top + ", \"frames\": [" + frames + "]}");
}

// Expects Dataset::load to throw InputError whose message names `file_part` and `field`.
void expect_bad(const std::string& dir, const std::string& file_part, const std::string& field) {
  try {
    Dataset::load(dir);
    FAIL() << "expected an InputError naming " << file_part << " / " << field;
  } catch (const InputError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find(file_part), std::string::npos) << msg;
    EXPECT_NE(msg.find(field), std::string::npos) << msg;
    EXPECT_EQ(msg.find('\n'), std::string::npos) << "one line: " << msg;
  }
}

}  // namespace

TEST(Downscale, StraightAlphaBoxAverageBeforeCompositing) {
  // 2x2 RGBA block: one opaque red pixel, three fully transparent (RGB garbage = green).
  auto im = torch::zeros({2, 2, 4});
  im.index_put_({0, 0}, torch::tensor({1.f, 0.f, 0.f, 1.f}));
  for (auto [r, c] : {std::pair{0, 1}, {1, 0}, {1, 1}}) im.index_put_({r, c}, torch::tensor({0.f, 1.f, 0.f, 0.f}));
  auto d = box_downscale(im, 2);
  ASSERT_EQ(d.size(0), 1);
  // straight average: rgb = (0.25, 0.75, 0), alpha = 0.25 (hand-computed)
  EXPECT_FLOAT_EQ(d[0][0][0].item<float>(), 0.25f);
  EXPECT_FLOAT_EQ(d[0][0][1].item<float>(), 0.75f);
  EXPECT_FLOAT_EQ(d[0][0][3].item<float>(), 0.25f);
  // 4x6 image of values r*6+c downscaled by 2: each output = mean of its 2x2 block.
  auto g = torch::arange(24, torch::kFloat).reshape({4, 6, 1});
  auto g2 = box_downscale(g, 2);
  EXPECT_EQ(g2.sizes(), (std::vector<int64_t>{2, 3, 1}));
  EXPECT_FLOAT_EQ(g2[1][2][0].item<float>(), (16 + 17 + 22 + 23) / 4.0f);
}

TEST(Dataset, CompositesOnWhiteOrBlack) {
  test::TempDir t;
  make_blender(t.path(), 1, 4, 4);
  // make pixel (0,0) half transparent
  auto img = read_png(t / "train/r_0.png");
  img[0][0][3] = 51;  // alpha 0.2
  write_png(t / "train/r_0.png", img);
  Dataset white = Dataset::load(t.path());
  const float a = 51 / 255.f, r = 200 / 255.f;
  EXPECT_NEAR(white.split("train").images[0][0][0][0].item<float>(), r * a + (1 - a), 1e-6);
  LoadOptions o;
  o.white_background = false;
  Dataset black = Dataset::load(t.path(), o);
  EXPECT_NEAR(black.split("train").images[0][0][0][0].item<float>(), r * a, 1e-6);
  EXPECT_NEAR(black.split("train").alpha[0][0][0].item<float>(), a, 1e-6);
  EXPECT_FALSE(white.has("val"));  // a missing split file means the split is absent
  EXPECT_FALSE(white.has("test"));
  EXPECT_DOUBLE_EQ(white.near, 2.0);
  EXPECT_DOUBLE_EQ(white.far, 6.0);
}

TEST(Dataset, FocalFromAngleAfterDownscale) {
  test::TempDir t;
  make_blender(t.path(), 2, 8, 8);
  LoadOptions o;
  o.downscale = 2;
  o.near = 1.5;
  o.far = 7.0;
  Dataset ds = Dataset::load(t.path(), o);
  EXPECT_EQ(ds.intrinsics.width, 4);
  EXPECT_NEAR(ds.intrinsics.fx, 0.5 * 4 / std::tan(0.5 * 0.6911112070083618), 1e-9);
  EXPECT_DOUBLE_EQ(ds.near, 1.5);
  EXPECT_DOUBLE_EQ(ds.far, 7.0);
  EXPECT_EQ(ds.split("train").images.sizes(), (std::vector<int64_t>{2, 4, 4, 3}));
}

TEST(Dataset, NotesADownscaleThatLeavesTinyImages) {
  // 128x96 photos: factor 2 keeps 64x48 (short side under kSmallImageSide), factor 1 never warns,
  // and a 1024x768 capture at factor 8 keeps 128x96.
  EXPECT_EQ(small_image_note(96, 128, 1), "");
  EXPECT_EQ(small_image_note(768, 1024, 8), "");
  EXPECT_EQ(small_image_note(128, 128, 2), "");
  const std::string note = small_image_note(96, 128, 2);
  EXPECT_NE(note.find("64x48"), std::string::npos) << note;
  EXPECT_NE(note.find("data.downscale = 2"), std::string::npos) << note;
  EXPECT_NE(note.find("128x96"), std::string::npos) << note;
  // The loader puts it among the dataset's notes (what `info` prints).
  test::TempDir t;
  make_blender(t.path(), 2, 16, 16);
  LoadOptions o;
  o.downscale = 4;
  const Dataset ds = Dataset::load(t.path(), o);
  ASSERT_FALSE(ds.notes.empty());
  EXPECT_NE(ds.notes.back().find("4x4-pixel"), std::string::npos) << ds.notes.back();
  EXPECT_TRUE(Dataset::load(t.path()).notes.empty());
}

TEST(Dataset, LoadingKeepsTheCallersThreadCount) {
  // Loading leaves LibTorch's intra-op thread count alone: the count is per thread, and a thread
  // that starts later takes the last value any thread set, so a change made while decoding would
  // reach training (one thread, or a count that depends on the decoders' timing).
  test::TempDir t;
  make_blender(t.path(), 6, 8, 8);
  for (const int threads : {2, 3}) {
    const test::IntraOpThreads scope(threads);
    (void)Dataset::load(t.path());
    EXPECT_EQ(at::get_num_threads(), threads);
  }
}

TEST(Dataset, InstantNgpTransformsJson) {
  test::TempDir t;
  make_blender(t.path(), 9, 6, 4);
  fs::remove(t / "transforms_train.json");
  // Cameras 0.5 apart along x, all looking down -z.
  const auto frames_with = [](const std::string& extra) {
    std::string frames;
    for (int i = 0; i < 9; ++i)
      frames += std::string(i ? "," : "") + "{\"file_path\": \"train/r_" + std::to_string(i) + ".png\", " + extra +
                "\"transform_matrix\": [[1,0,0," + std::to_string(0.5 * i) + "],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}";
    return frames;
  };
  const std::string frames = frames_with("");
  test::write_file(t / "transforms.json", std::string("{\"fl_x\": 5.0, \"fl_y\": 6.0, \"cx\": 3.1, \"cy\": 1.9, ") +
                                              "\"w\": 6, \"h\": 4, \"frames\": [" + frames + "]}");
  Dataset ds = Dataset::load(t.path());
  EXPECT_EQ(ds.format, "instant-ngp");
  EXPECT_DOUBLE_EQ(ds.intrinsics.fx, 5.0);
  EXPECT_DOUBLE_EQ(ds.intrinsics.fy, 6.0);
  EXPECT_DOUBLE_EQ(ds.intrinsics.cx, 3.1);
  EXPECT_EQ(ds.intrinsics.model, LensModel::Pinhole);
  EXPECT_EQ(ds.split("test").size(), 2);  // frames 0 and 8 held out
  EXPECT_EQ(ds.split("train").size(), 7);
  // The scene frame: centred on the mean camera (parallel axes have no focus point), farthest
  // camera at distance 1, up (+y of the cameras) turned to +z.
  EXPECT_EQ(ds.scene.kind, SceneKind::Unbounded);
  EXPECT_NEAR(ds.scene.scale, 1.0 / 2.0, 1e-9);
  const auto centres = torch::cat({ds.split("train").c2w, ds.split("test").c2w}).select(2, 3);
  EXPECT_NEAR(centres.norm(2, 1).max().item<double>(), 1.0, 1e-6);
  EXPECT_NEAR(ds.split("train").c2w[0][2][1].item<double>(), 1.0, 1e-6);  // camera up is world +z
  // Lens distortion and per-frame intrinsics are read.
  test::write_file(t / "transforms.json",
                   std::string("{\"fl_x\": 5.0, \"k1\": 0.1, \"p2\": 0.01, \"w\": 6, \"h\": 4, \"frames\": [") +
                       frames_with("\"fl_x\": 7.0, ") + "]}");
  ds = Dataset::load(t.path());
  EXPECT_EQ(ds.intrinsics.model, LensModel::RadialTangential);
  EXPECT_DOUBLE_EQ(ds.intrinsics.dist[kK1], 0.1);
  EXPECT_DOUBLE_EQ(ds.intrinsics.dist[kP2], 0.01);
  EXPECT_DOUBLE_EQ(ds.intrinsics.fx, 7.0);
  // A camera model it cannot cast rays through, and every camera at one point, are refused.
  test::write_file(
      t / "transforms.json",
      std::string("{\"fl_x\": 5.0, \"camera_model\": \"EQUIRECTANGULAR\", \"w\": 6, \"h\": 4, \"frames\": [") + frames +
          "]}");
  expect_bad(t.path(), "transforms.json", "camera_model");
  std::string same;
  for (int i = 0; i < 9; ++i)
    same += std::string(i ? "," : "") + "{\"file_path\": \"train/r_" + std::to_string(i) +
            ".png\", \"transform_matrix\": " + kIdentityPose + "}";
  test::write_file(t / "transforms.json",
                   std::string("{\"fl_x\": 5.0, \"w\": 6, \"h\": 4, \"frames\": [") + same + "]}");
  expect_bad(t.path(), "", "poses");
}

TEST(Dataset, LegoScene) {
  const std::string lego = test::lego_dir();
  if (lego.empty()) GTEST_SKIP() << "../shared/data/nerf_synthetic/lego not present";
  LoadOptions o;
  o.downscale = 8;  // the loader path is the same at every factor; 8x keeps the test fast
  Dataset ds = Dataset::load(lego, o);
  EXPECT_EQ(ds.split("train").size(), 100);
  EXPECT_EQ(ds.split("test").size(), 200);
  EXPECT_FALSE(ds.has("val"));
  // The test views' depth maps beside their images (data/depth_file.h); the train views have none.
  EXPECT_FALSE(ds.split("train").depth.defined());
  ASSERT_TRUE(ds.split("test").depth.defined());
  EXPECT_EQ(ds.split("test").depth.sizes(), (std::vector<int64_t>{200, 100, 100}));
  EXPECT_EQ(ds.intrinsics.width, 100);
  // focal 1111.11 at 800 px -> 138.89 at 100 px
  EXPECT_NEAR(ds.intrinsics.fx * 8, 1111.1110311937682, 1e-4);
  // every camera sits about 4.03 units from the origin on the upper hemisphere (Blender lego)
  auto centres = ds.split("train").c2w.select(2, 3);
  auto dist = centres.norm(2, 1);
  EXPECT_NEAR(dist.min().item<double>(), 4.031128, 1e-3);
  EXPECT_NEAR(dist.max().item<double>(), 4.031128, 1e-3);
  // the corners of every image are background: composited white
  auto imgs = ds.split("train").images;
  EXPECT_GT(imgs.select(1, 0).select(1, 0).min().item<float>(), 0.99f);
  // the lego pixels are not all white: mean alpha of a view is well inside (0,1)
  const double ma = ds.split("train").alpha.mean().item<double>();
  EXPECT_GT(ma, 0.05);
  EXPECT_LT(ma, 0.6);
}

TEST(BadInput, MalformedJson) {
  test::TempDir t;
  make_blender(t.path(), 1, 4, 4);
  test::write_file(t / "transforms_train.json", "{\"camera_angle_x\": 0.69, \"frames\": [");
  expect_bad(t.path(), "transforms_train.json", "invalid JSON");
}

TEST(BadInput, MissingCameraAngle) {
  test::TempDir t;
  make_blender(t.path(), 1, 4, 4, kIdentityPose, "\"fov\": 1");
  expect_bad(t.path(), "transforms_train.json", "camera_angle_x");
}

// Found by the fuzz smoke run: an angle of 0 gave an infinite focal length (tan(0) = 0).
TEST(BadInput, CameraAngleOutsideZeroToPi) {
  for (const char* angle : {"0", "-0.5", "3.2"}) {
    test::TempDir t;
    make_blender(t.path(), 1, 4, 4, kIdentityPose, std::string("\"camera_angle_x\": ") + angle);
    SCOPED_TRACE(angle);
    expect_bad(t.path(), "transforms_train.json", "camera_angle_x");
  }
}

TEST(BadInput, ZeroFrames) {
  test::TempDir t;
  make_blender(t.path(), 1, 4, 4);
  test::write_file(t / "transforms_train.json", "{\"camera_angle_x\": 0.69, \"frames\": []}");
  expect_bad(t.path(), "transforms_train.json", "frames");
}

TEST(BadInput, MissingImage) {
  test::TempDir t;
  make_blender(t.path(), 2, 4, 4);
  fs::remove(t / "train/r_1.png");
  expect_bad(t.path(), "transforms_train.json", "frames[1].file_path");
}

TEST(BadInput, TruncatedImage) {
  test::TempDir t;
  make_blender(t.path(), 2, 16, 16);
  const auto p = t / "train/r_1.png";
  const auto size = fs::file_size(p);
  fs::resize_file(p, size / 2);
  expect_bad(t.path(), "r_1.png", "PNG");
}

TEST(BadInput, NotAPng) {
  test::TempDir t;
  make_blender(t.path(), 1, 4, 4);
  test::write_file(t / "train/r_0.png", "this is not an image");
  expect_bad(t.path(), "r_0.png", "PNG");
}

TEST(BadInput, ImagesOfDifferentSizes) {
  test::TempDir t;
  make_blender(t.path(), 2, 4, 4);
  write_png(t / "train/r_1.png", torch::zeros({5, 4, 4}, torch::kUInt8));
  expect_bad(t.path(), "r_1.png", "frames[1].file_path");
}

TEST(BadInput, NonFinitePose) {
  test::TempDir t;
  // JSON has no NaN literal; an overflowing number parses to inf.
  make_blender(t.path(), 1, 4, 4, "[[1e999,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]");
  expect_bad(t.path(), "transforms_train.json", "frames[0].transform_matrix");
  test::TempDir t2;  // Python's json.dump writes NaN literals
  make_blender(t2.path(), 2, 4, 4, "[[1,0,0,0],[0,1,0,NaN],[0,0,1,4],[0,0,0,1]]");
  expect_bad(t2.path(), "transforms_train.json", "frames[0].transform_matrix: non-finite");
}

TEST(BadInput, NonRigidPose) {
  test::TempDir t;
  make_blender(t.path(), 1, 4, 4, "[[2,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]");
  expect_bad(t.path(), "transforms_train.json", "frames[0].transform_matrix");
  test::TempDir t2;  // a reflection (det -1) is not a camera pose either
  make_blender(t2.path(), 1, 4, 4, "[[-1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]");
  expect_bad(t2.path(), "transforms_train.json", "rigid");
}

TEST(BadInput, PathOutsideDataset) {
  test::TempDir t;
  make_blender(t.path(), 1, 4, 4);
  test::write_file(t / "transforms_train.json",
                   std::string("{\"camera_angle_x\": 0.69, \"frames\": [{\"file_path\": \"../../etc/passwd\", "
                               "\"transform_matrix\": ") +
                       kIdentityPose + "}]}");
  expect_bad(t.path(), "transforms_train.json", "outside");
}

TEST(BadInput, MissingFolder) { expect_bad("/nonexistent/ablenerf/data", "/nonexistent/ablenerf/data", "not found"); }

// The registry of capture formats (data/capture.h): detection by file names in the table's order,
// the first match reading the folder; a folder no row claims is refused naming it.
TEST(CaptureRegistry, DetectsEachFormatByItsFilesInTableOrder) {
  std::vector<std::string> names;
  for (const auto& f : capture_formats()) names.push_back(f.name);
  EXPECT_EQ(names, (std::vector<std::string>{"blender", "transforms", "colmap", "llff"}));
  test::TempDir t;
  const std::string d = t / "capture";
  fs::create_directories(d + "/sparse/0");
  EXPECT_EQ(capture_format(d), "");
  try {
    read_capture(d, {}, 1);
    ADD_FAILURE() << "an empty folder was read";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find(d), std::string::npos) << e.what();
  }
  // Each format's file added in turn; an earlier row of the table wins over a later one.
  const std::vector<std::pair<std::string, std::string>> files{{"poses_bounds.npy", "llff"},
                                                               {"sparse/0/cameras.txt", "colmap"},
                                                               {"transforms.json", "transforms"},
                                                               {"transforms_test.json", "blender"}};
  for (const auto& [file, format] : files) {
    test::write_file(d + "/" + file, "");
    EXPECT_EQ(capture_format(d), format) << file;
  }
}

// Dataset::load of a Capture already read loads what Dataset::load of the folder does, keeping only
// the splits asked for; the split names come from the one read.
TEST(CaptureRegistry, LoadingACaptureReadOnceEqualsLoadingTheFolder) {
  test::TempDir t;
  make_blender(t / "scene", 3, 6, 4);
  const Capture capture = read_capture(t / "scene", {}, 1);
  EXPECT_EQ(capture.format, "blender");
  EXPECT_EQ(capture.split_names(), std::vector<std::string>{"train"});
  LoadOptions o;
  o.splits = {"train"};
  const Dataset once = Dataset::load(capture, t / "scene", o), folder = Dataset::load(t / "scene", o);
  EXPECT_TRUE(torch::equal(once.split("train").images, folder.split("train").images));
  EXPECT_TRUE(torch::equal(once.split("train").c2w, folder.split("train").c2w));
  o.splits = {"test"};
  EXPECT_THROW(Dataset::load(capture, t / "scene", o), InputError);
}
