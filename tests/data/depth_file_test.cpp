// The depth maps of NeRF's Blender scenes (data/depth_file.h): the value-to-depth map in closed
// form, the loader picking the files up for the splits that have them, and, on lego when
// ../shared/data is present, the map checked against the scene's own geometry: neighbouring views'
// depth maps must agree where they see the same surface.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "data/depth_file.h"
#include "data/dataset.h"
#include "test_util.h"
#include "util/image_io.h"

using namespace ablenerf;
namespace fs = std::filesystem;

TEST(BlenderDepth, ValueIsTheRayDistanceFromTheFarEnd) {
  const Intrinsics k = test::pinhole(3, 2, 2.0, 4.0, 1.0, 1.5);
  auto png = torch::zeros({2, 3, 4}, torch::kUInt8);
  const int values[2][3] = {{0, 255, 128}, {51, 1, 200}};
  for (int r = 0; r < 2; ++r)
    for (int c = 0; c < 3; ++c) png.index_put_({r, c}, values[r][c]);  // every channel alike, as the files
  const auto z = blender_depth_to_z(png, k);
  ASSERT_EQ(z.sizes(), (std::vector<int64_t>{2, 3}));
  for (int r = 0; r < 2; ++r)
    for (int c = 0; c < 3; ++c) {
      const double x = (c + 0.5 - 1.0) / 2.0, y = (r + 0.5 - 1.5) / 4.0;
      const double dist = 8.0 * (1.0 - values[r][c] / 255.0);
      const double want = values[r][c] == 0 ? 0.0 : dist / std::sqrt(1.0 + x * x + y * y);
      EXPECT_NEAR(z[r][c].item<double>(), want, 1e-6) << r << "," << c;
    }
}

TEST(BlenderDepth, LoaderReadsTheFilesBesideTheImagesOfTheSplitsThatHaveThem) {
  test::TempDir t;
  fs::create_directories(t / "train");
  fs::create_directories(t / "test");
  const std::string pose = "[[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]";
  auto img = torch::full({4, 4, 4}, 255, torch::kUInt8);
  for (const char* split : {"train", "test"}) {
    write_png(t / (std::string(split) + "/r_0.png"), img);
    test::write_file(t / (std::string("transforms_") + split + ".json"),
                     std::string(R"({"camera_angle_x": 0.5, "frames": [{"file_path": "./)") + split +
                         R"(/r_0", "transform_matrix": )" + pose + "}]}");
  }
  auto depth = torch::full({4, 4, 4}, 100, torch::kUInt8);
  depth.index_put_({0, 0}, 0);  // background
  write_png(t / "test/r_0_depth_0001.png", depth);
  const Dataset ds = Dataset::load(t.path());
  EXPECT_FALSE(ds.split("train").depth.defined());
  ASSERT_TRUE(ds.split("test").depth.defined());
  const auto d = ds.split("test").depth[0];
  const double f = 2.0 / std::tan(0.25);  // 0.5 w / tan(angle / 2), w = 4
  const double x = (3 + 0.5 - 2.0) / f, y = (2 + 0.5 - 2.0) / f;
  EXPECT_NEAR(d[2][3].item<double>(), 8.0 * (1.0 - 100.0 / 255.0) / std::sqrt(1 + x * x + y * y), 1e-5);
  EXPECT_EQ(d[0][0].item<double>(), 0.0);
}

namespace {

struct View {
  torch::Tensor z;    // (H, W) camera-space depth, 0 on the background
  torch::Tensor c2w;  // (4, 4), OpenGL axes
};

// Median |z_j(X) - map_j(project_j(X))| over view i's pixels X (every `stride`-th row and column)
// that land inside view j on its object: how far the two maps disagree about the same points.
double disagreement(const View& a, const View& b, double f, int64_t stride) {
  const int64_t h = a.z.size(0), w = a.z.size(1);
  const auto zi = a.z.index({torch::indexing::Slice(0, h, stride), torch::indexing::Slice(0, w, stride)});
  const auto rows = torch::arange(0, h, stride, torch::kDouble).unsqueeze(1).expand_as(zi);
  const auto cols = torch::arange(0, w, stride, torch::kDouble).unsqueeze(0).expand_as(zi);
  const auto keep = zi > 0;
  const auto z = zi.index({keep}).to(torch::kDouble);
  const auto x = (cols.index({keep}) + 0.5 - w / 2.0) / f * z, y = -(rows.index({keep}) + 0.5 - h / 2.0) / f * z;
  const auto cam = torch::stack({x, y, -z, torch::ones_like(z)}, 1);  // (N, 4)
  const auto in_j = torch::matmul(torch::matmul(torch::inverse(b.c2w), a.c2w), cam.t()).t();
  const auto zj = -in_j.select(1, 2);
  const auto u = in_j.select(1, 0) / zj * f + w / 2.0, v = -in_j.select(1, 1) / zj * f + h / 2.0;
  const auto inside = (zj > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h);
  const auto ui = u.index({inside}).to(torch::kLong), vi = v.index({inside}).to(torch::kLong);
  const auto seen = b.z.to(torch::kDouble).index({vi, ui});
  const auto on = seen > 0;
  return (zj.index({inside}).index({on}) - seen.index({on})).abs().median().item<double>();
}

}  // namespace

// The map fitted by multi-view consistency holds on views it was not checked on, and beats the
// reading of the same values as z-depth: the test fails if either the constants or the
// ray-distance reading were wrong.
TEST(BlenderDepth, LegoNeighbouringViewsAgree) {
  const std::string lego = test::lego_dir();
  if (lego.empty()) GTEST_SKIP() << "../shared/data/nerf_synthetic/lego not present";
  std::ifstream in(lego + "/transforms_test.json");
  const auto meta = nlohmann::json::parse(in);
  const double f = 400.0 / std::tan(0.5 * meta.at("camera_angle_x").get<double>());
  const Intrinsics k = test::pinhole(800, 800, f, f, 400.0, 400.0);
  auto view = [&](int i, bool as_ray_distance) {
    const auto& fr = meta.at("frames").at(i);
    const std::string file = lego + "/" + fr.at("file_path").get<std::string>() + "_depth_0001.png";
    View v;
    const auto png = read_png(file);
    v.z = as_ray_distance
              ? blender_depth_to_z(png, k)
              : torch::where(png.select(2, 0) > 0, 8.0 * (1.0 - png.select(2, 0).to(torch::kDouble) / 255.0),
                             torch::zeros({800, 800}, torch::kDouble))
                    .to(torch::kFloat);
    std::vector<double> m;
    for (const auto& row : fr.at("transform_matrix"))
      for (const auto& e : row) m.push_back(e.get<double>());
    v.c2w = torch::tensor(m, torch::kDouble).view({4, 4});
    return v;
  };
  // Test views 5 / 15 and 105 / 115 (the fit used 0, 10, ..., 190): ~18 degrees apart.
  for (const auto& pair : {std::pair<int, int>{5, 15}, {105, 115}}) {
    const double ray = disagreement(view(pair.first, true), view(pair.second, true), f, 4);
    const double zread = disagreement(view(pair.first, false), view(pair.second, false), f, 4);
    EXPECT_LT(ray, 0.025) << pair.first << " -> " << pair.second;  // under one 8-bit step (0.031)
    EXPECT_GT(zread, 1.5 * ray) << pair.first << " -> " << pair.second;
  }
}
