// Run folders: create/open round trip, refusal of folders that are not runs, and the removal of
// the temporaries an interrupted atomic write leaves behind (and of nothing else).
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>

#include "run/run_folder.h"
#include "test_util.h"
#include "util/errors.h"
#include "util/fs.h"
#include "model/model_config.h"

using namespace ablenerf;
namespace fs = std::filesystem;

namespace {

std::vector<std::string> names_in(const std::string& dir) {
  std::vector<std::string> out;
  for (const auto& e : fs::directory_iterator(dir)) out.push_back(e.path().filename().string());
  std::sort(out.begin(), out.end());
  return out;
}

}  // namespace

TEST(RunFolder, CreateThenOpenGivesTheSameConfigAndDataFolder) {
  test::TempDir t;
  fs::create_directories(t / "data");
  Config c;
  c.set("model.width=48");
  c.set("train.steps=7");
  c.validate();
  const RunFolder made = RunFolder::create(t / "run", c, t / "data");
  EXPECT_EQ(made.weights_path(), t / "run/weights.pt");
  EXPECT_EQ(made.checkpoint_path(), t / "run/checkpoint.pt");
  EXPECT_EQ(made.log_path(), t / "run/log.jsonl");
  const RunFolder opened = RunFolder::open(t / "run");
  EXPECT_EQ(opened.config.to_toml(), c.to_toml());
  EXPECT_EQ(opened.config.get<ModelConfig>().width, 48);
  EXPECT_EQ(opened.data_dir, fs::absolute(t / "data").lexically_normal().string());
}

TEST(RunFolder, OpenRefusesWhatIsNotARun) {
  test::TempDir t;
  EXPECT_THROW(RunFolder::open(t / "absent"), InputError);
  fs::create_directories(t / "empty");
  try {
    RunFolder::open(t / "empty");
    FAIL() << "opened a folder without config.toml";
  } catch (const InputError& e) {
    EXPECT_EQ(e.file(), t / "empty/config.toml");
  }
}

TEST(RunFolder, RemovesOnlyTheTemporariesOfItsOwnOutputs) {
  test::TempDir t;
  const RunFolder run = RunFolder::create(t / "run", Config{}, "");
  const std::vector<std::string> stale = {
      atomic_temp_prefix(run.checkpoint_path()) + "123_0", atomic_temp_prefix(run.weights_path()) + "9_4",
      atomic_temp_prefix(run.path("config.toml")) + "77_1", atomic_temp_prefix(run.path("run.json")) + "5_0",
      atomic_temp_prefix(run.report_path()) + "12_3"};
  for (const auto& f : stale) test::write_file(f, "partial");
  // Real outputs and files that are not temporaries of the run's outputs stay.
  for (const char* keep : {"weights.pt", "checkpoint.pt", "log.jsonl", "notes.tmp", "frame.png.tmp1_1"})
    test::write_file(run.path(keep), "keep");
  run.remove_stale_temporaries();
  EXPECT_EQ(names_in(run.dir), (std::vector<std::string>{"checkpoint.pt", "config.toml", "frame.png.tmp1_1",
                                                         "log.jsonl", "notes.tmp", "run.json", "weights.pt"}));
  EXPECT_EQ(read_file(run.weights_path()), "keep");
}
