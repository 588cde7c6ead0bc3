// `ablenerf export` / `ablenerf import` end to end through the built CLI.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <filesystem>
#include <fstream>

#include "eval/eval_fixtures.h"
#include "model/able_nerf.h"
#include "test_util.h"
#include "model/model_config.h"

namespace ablenerf {
namespace {

std::string demo_config() { return test::source_dir() + "/configs/demo.toml"; }

TEST(ExportImportCli, ExportOfAFreshModelRoundTripsExactly) {
  test::TempDir dir;
  const auto r = test::run_cli("export --config " + demo_config() + " --seed 9 --out " + (dir / "w.pt"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  Config c = Config::load(demo_config());
  torch::manual_seed(9);
  AbleNerf expected(c.get<ModelConfig>());  // same seed, same construction order -> same init
  torch::manual_seed(10);
  AbleNerf loaded(c.get<ModelConfig>());
  load_weights(loaded, dir / "w.pt");
  for (const auto& p : expected->named_parameters())
    EXPECT_TRUE(torch::equal(p.value(), loaded->named_parameters()[p.key()])) << p.key();
}

TEST(ExportImportCli, ImportThenExportKeepsReleaseValues) {
  test::TempDir dir;
  // A release-named dictionary for the demo model, built from our own names' mapping.
  Config c = Config::load(demo_config());
  AbleNerf shape_model(c.get<ModelConfig>());
  const auto ours = shape_model->named_parameters();
  c10::impl::GenericDict dict(c10::StringType::get(), c10::TensorType::get());
  torch::manual_seed(3);
  for (const auto& [rel, name] : release_name_map(c.get<ModelConfig>()))
    dict.insert("model." + rel, torch::randn(ours[name].sizes()));
  const auto bytes = torch::pickle_save(c10::IValue(dict));
  std::ofstream(dir / "rel.pt", std::ios::binary).write(bytes.data(), static_cast<std::streamsize>(bytes.size()));

  auto r =
      test::run_cli("import --weights " + (dir / "rel.pt") + " --config " + demo_config() + " --out " + (dir / "run"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = test::run_cli("export --run " + (dir / "run") + " --out " + (dir / "out.pt"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  AbleNerf loaded(c.get<ModelConfig>());
  load_weights(loaded, dir / "out.pt");
  const auto p = loaded->named_parameters();
  EXPECT_TRUE(torch::equal(p["le"], dict.at("model.light_probes").toTensor()));
  EXPECT_TRUE(torch::equal(p["fine.blocks.0.ff_in.bias"], dict.at("model.fine.layers.0.ff_layer.0.bias").toTensor()));

  // A wrong shape is one line naming the release parameter, exit code 2.
  dict.insert_or_assign("model.color_token", torch::zeros({1, 1, 7}));
  const auto bad = torch::pickle_save(c10::IValue(dict));
  std::ofstream(dir / "bad.pt", std::ios::binary).write(bad.data(), static_cast<std::streamsize>(bad.size()));
  r = test::run_cli("import --weights " + (dir / "bad.pt") + " --config " + demo_config() + " --out " + (dir / "run2"));
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_EQ(r.output, "error: " + (dir / "bad.pt") + ": color_token: expected shape [1, 1, " +
                          std::to_string(c.get<ModelConfig>().width) + "] got [1, 1, 7]\n");
}

TEST(ExportImportCli, ExportNeedsExactlyOneSource) {
  const auto r = test::run_cli("export --out /tmp/never.pt");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("--run"), std::string::npos);
}

// A run too early to hold a surface (an untrained model: its depth maps agree on no point) is
// refused in one line that names the run, not a flag such as --crop, and nothing is written.
TEST(ExportImportCli, ARunWithoutSurfacesIsRefusedNamingTheRun) {
  test::TempDir t;
  test::make_tiny_scene(t / "scene", 2, 1, 8, 8, false);
  test::make_tiny_run(t / "run", t / "scene");
  const auto r = test::run_cli("export --run " + t / "run" + " --points " + t / "points.ply" +
                               " --views 2 --max-side 8 --preview none --quiet");
  if (r.output.find("no geometry export") != std::string::npos) GTEST_SKIP() << "built without Open3D";
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << r.output;
  EXPECT_NE(r.output.find("--run"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("no surface point"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("--crop"), std::string::npos) << r.output;
  EXPECT_FALSE(std::filesystem::exists(t / "points.ply"));
}

}  // namespace
}  // namespace ablenerf
