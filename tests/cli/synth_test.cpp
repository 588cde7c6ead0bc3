// `ablenerf synth` through the built CLI ($ABLENERF_BIN, set by ctest), read back by `info`.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "test_util.h"

using namespace ablenerf;
namespace fs = std::filesystem;

namespace {

// The CLI binary is built separately (target `ablenerf`); ctest passes its path.
bool have_cli() {
  const char* bin = std::getenv("ABLENERF_BIN");
  return bin != nullptr && fs::exists(bin);
}

TEST(SynthCli, WritesADatasetThatInfoReads) {
  if (!have_cli()) GTEST_SKIP() << "no CLI binary at $ABLENERF_BIN (build target ablenerf, run through ctest)";
  test::TempDir tmp("synth_cli");
  const std::string out = tmp / "demo";
  const auto r = test::run_cli("synth --out " + out + " --res 32 --train-views 4 --test-views 2");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("6/6 views"), std::string::npos) << r.output;  // progress line
  EXPECT_NE(r.output.find("wrote 4 train + 2 test"), std::string::npos) << r.output;

  const auto info = test::run_cli("info --data " + out);
  ASSERT_EQ(info.exit_code, 0) << info.output;
  const auto j = nlohmann::json::parse(info.output.substr(info.output.find('{')));
  const auto& ds = j.at("dataset");
  EXPECT_EQ(ds.at("width").get<int>(), 32);
  EXPECT_EQ(ds.at("height").get<int>(), 32);
  EXPECT_EQ(ds.at("splits").at("train").at("count").get<int>(), 4);
  EXPECT_EQ(ds.at("splits").at("test").at("count").get<int>(), 2);
  EXPECT_TRUE(ds.at("splits").at("test").at("has_depth").get<bool>());
  EXPECT_NEAR(ds.at("splits").at("train").at("camera_distance_min").get<double>(), 4.0, 1e-5);
  EXPECT_NEAR(ds.at("splits").at("train").at("camera_distance_max").get<double>(), 4.0, 1e-5);
  // Objects cover part of the frame, background the rest.
  const double alpha = ds.at("splits").at("test").at("mean_alpha").get<double>();
  EXPECT_GT(alpha, 0.05);
  EXPECT_LT(alpha, 0.6);
}

TEST(SynthCli, BadArgumentsExitWithCode2AndWriteNothing) {
  if (!have_cli()) GTEST_SKIP() << "no CLI binary at $ABLENERF_BIN (build target ablenerf, run through ctest)";
  test::TempDir tmp("synth_cli_bad");
  const std::string out = tmp / "demo";
  auto r = test::run_cli("synth --out " + out + " --res 0");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("error: synth: --res:"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(out));
  r = test::run_cli("synth --out " + out + " --train-views 0");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("--train-views"), std::string::npos) << r.output;
  r = test::run_cli("synth --res 32");  // --out is required
  EXPECT_EQ(r.exit_code, 2) << r.output;
}

}  // namespace
