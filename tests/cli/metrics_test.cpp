// `ablenerf metrics` through the built CLI ($ABLENERF_BIN): the JSON it prints against the library's
// scores, and one-line errors with exit code 2.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cstdlib>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "eval/metrics.h"
#include "test_util.h"
#include "util/image_io.h"

namespace ablenerf {
namespace {

bool cli_available() {
  const char* bin = std::getenv("ABLENERF_BIN");
  return bin && std::filesystem::exists(bin);
}

TEST(MetricsCli, IdenticalImagesScorePerfectly) {
  if (!cli_available()) GTEST_SKIP() << "ABLENERF_BIN not built";
  test::TempDir dir("metrics");
  torch::manual_seed(3);
  write_png(dir / "x.png", torch::rand({40, 36, 3}));
  const std::string pair = "metrics --ref " + (dir / "x.png") + " --img " + (dir / "x.png");
  auto r = test::run_cli(pair + " --ssim release");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  auto j = nlohmann::json::parse(r.output);
  EXPECT_TRUE(j["psnr"].is_null());  // +infinity has no JSON form; explained in psnr_note
  EXPECT_TRUE(j["psnr_note"].is_string());
  EXPECT_EQ(j["mse"].get<double>(), 0.0);
  EXPECT_NEAR(j["ssim"].get<double>(), 1.0, 1e-9);
  EXPECT_EQ(j["ssim_variant"], "release");
  if (j["lpips"].is_null())
    EXPECT_TRUE(j["lpips_note"].is_string());
  else
    EXPECT_NEAR(j["lpips"].get<double>(), 0.0, 1e-6);
}

TEST(MetricsCli, MatchesLibraryOnDifferentImages) {
  if (!cli_available()) GTEST_SKIP() << "ABLENERF_BIN not built";
  test::TempDir dir("metrics");
  torch::manual_seed(4);
  write_png(dir / "a.png", torch::rand({20, 24, 3}));
  write_png(dir / "b.png", torch::rand({20, 24, 3}));
  auto r = test::run_cli("metrics --ref " + (dir / "a.png") + " --img " + (dir / "b.png"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  auto j = nlohmann::json::parse(r.output);
  auto a = read_rgb_for_metrics(dir / "a.png"), b = read_rgb_for_metrics(dir / "b.png");
  EXPECT_NEAR(j["psnr"].get<double>(), psnr(b, a), 1e-9);
  EXPECT_NEAR(j["ssim"].get<double>(), ssim(b, a), 1e-9);
  EXPECT_EQ(j["ssim_variant"], "standard");
  // 20x24 is below AlexNet's minimum input, so LPIPS is reported as skipped.
  EXPECT_TRUE(j["lpips"].is_null());
  EXPECT_TRUE(j["lpips_note"].is_string());
}

TEST(MetricsCli, MismatchedSizesExitTwoNamingBothFiles) {
  if (!cli_available()) GTEST_SKIP() << "ABLENERF_BIN not built";
  test::TempDir dir("metrics");
  write_png(dir / "small.png", torch::zeros({12, 12, 3}));
  write_png(dir / "large.png", torch::zeros({12, 13, 3}));
  auto r = test::run_cli("metrics --ref " + (dir / "small.png") + " --img " + (dir / "large.png"));
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("small.png"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("large.png"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("error:"), std::string::npos) << r.output;
}

TEST(MetricsCli, BadOptionsExitTwo) {
  if (!cli_available()) GTEST_SKIP() << "ABLENERF_BIN not built";
  test::TempDir dir("metrics");
  write_png(dir / "x.png", torch::zeros({40, 40, 3}));
  const std::string pair = "metrics --ref " + (dir / "x.png") + " --img " + (dir / "x.png");
  auto r = test::run_cli(pair + " --ssim skimage");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("skimage"), std::string::npos) << r.output;
  // An explicit but missing LPIPS weights file is an input error naming the file.
  r = test::run_cli(pair + " --lpips-weights " + (dir / "none.pt"));
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("none.pt"), std::string::npos) << r.output;
  r = test::run_cli("metrics --ref " + (dir / "missing.png") + " --img " + (dir / "x.png"));
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("missing.png"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace ablenerf
