// The CLI end to end: `info` as the dataset validator, exit codes and one-line errors.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "test_util.h"

using namespace ablenerf;

TEST(Cli, HelpForEverySubcommand) {
  for (const char* sub : {"synth", "train", "eval", "render", "bench", "export", "import", "info", "metrics"}) {
    auto r = test::run_cli(std::string(sub) + " --help");
    EXPECT_EQ(r.exit_code, 0) << sub << ": " << r.output;
    EXPECT_NE(r.output.find("Usage"), std::string::npos) << sub;
  }
}

TEST(Cli, InfoOnLego) {
  const std::string lego = test::lego_dir();
  if (lego.empty()) GTEST_SKIP() << "lego not present";
  auto r = test::run_cli("info --data " + lego + " --set data.downscale=8");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  auto j = nlohmann::json::parse(r.output.substr(r.output.find('{')));
  EXPECT_EQ(j["dataset"]["splits"]["train"]["count"], 100);
  EXPECT_EQ(j["dataset"]["splits"]["test"]["count"], 200);
  EXPECT_EQ(j["dataset"]["width"], 100);
}

TEST(Cli, BadInputExitsTwoWithOneLine) {
  test::TempDir t;
  test::write_file(t / "transforms_train.json", "{ not json");
  auto r = test::run_cli("info --data " + t.path());
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("transforms_train.json"), std::string::npos) << r.output;
  // exactly one line of output
  EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << r.output;
  auto r2 = test::run_cli("info --data /nonexistent/dir");
  EXPECT_EQ(r2.exit_code, 2);
  auto r3 = test::run_cli("info --config /nonexistent.toml");
  EXPECT_EQ(r3.exit_code, 2);
  EXPECT_NE(r3.output.find("/nonexistent.toml"), std::string::npos) << r3.output;
  auto r4 = test::run_cli("info --set model.no_such_key=3");
  EXPECT_EQ(r4.exit_code, 2);
  EXPECT_NE(r4.output.find("model.no_such_key"), std::string::npos) << r4.output;
}
