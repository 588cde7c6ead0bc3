// RUN/log.jsonl: records appended by append_run_log read back by read_run_log; damaged lines
// skipped and counted; write and read failures reported naming the file.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>

#include "run/run_log.h"
#include "test_util.h"
#include "util/errors.h"
#include "util/fs.h"

using namespace ablenerf;
namespace fs = std::filesystem;

TEST(RunLog, AppendedRecordsReadBackInOrder) {
  test::TempDir t;
  const std::string path = t / "log.jsonl";
  append_run_log(path, {{"type", "train"}, {"step", 2}, {"loss", 0.5}, {"elapsed_s", 1.5}});
  append_run_log(path, {{"type", "eval"}, {"step", 2}, {"psnr", 11.0}, {"split", "test"}});
  append_run_log(path, {{"type", "train"}, {"step", 4}, {"loss", 0.25}, {"elapsed_s", 3.0}});
  // One object per line, nothing else.
  const std::string text = read_file(path);
  EXPECT_EQ(std::count(text.begin(), text.end(), '\n'), 3);
  EXPECT_EQ(text.back(), '\n');
  const RunLog log = read_run_log(path);
  ASSERT_EQ(log.train.size(), 2u);
  ASSERT_EQ(log.eval.size(), 1u);
  EXPECT_EQ(log.train[0]["step"], 2);
  EXPECT_EQ(log.train[1]["loss"], 0.25);
  EXPECT_EQ(log.eval[0]["split"], "test");
  EXPECT_EQ(log.last_step, 4);
  EXPECT_DOUBLE_EQ(log.elapsed_s, 3.0);
  EXPECT_EQ(log.skipped_lines, 0);
}

TEST(RunLog, SplitsByTypeAndSkipsDamagedLines) {
  test::TempDir t;
  test::write_file(t / "log.jsonl",
                   "{\"type\":\"train\",\"step\":10,\"loss\":0.5,\"psnr\":12,\"elapsed_s\":3.5}\n"
                   "{\"type\":\"eval\",\"step\":20,\"psnr\":14,\"views\":4,\"split\":\"val\"}\n"
                   "\n"
                   "{\"type\":\"train\",\"step\":20,\"loss\":0.4,\"psnr\":13,\"elapsed_s\":7.25}\n"
                   "{\"type\":\"train\",\"step\":30,\"lo");  // cut short by a crash
  const RunLog log = read_run_log(t / "log.jsonl");
  EXPECT_EQ(log.train.size(), 2u);
  EXPECT_EQ(log.eval.size(), 1u);
  EXPECT_EQ(log.last_step, 20);
  EXPECT_DOUBLE_EQ(log.elapsed_s, 7.25);
  EXPECT_EQ(log.skipped_lines, 1);
  const RunLog none = read_run_log(t / "absent.jsonl");
  EXPECT_TRUE(none.train.empty());
  EXPECT_EQ(none.last_step, -1);
}

TEST(RunLog, UnreadableLogIsReportedNotIgnored) {
  test::TempDir t;
  fs::create_directories(t / "log.jsonl");  // exists, but cannot be read as a file
  try {
    read_run_log(t / "log.jsonl");
    FAIL() << "an unreadable log was read as empty";
  } catch (const InputError& e) {
    EXPECT_EQ(e.file(), t / "log.jsonl");
  }
}

TEST(RunLog, AppendFailureIsAnEnvironmentErrorNamingTheFile) {
  test::TempDir t;
  const std::string path = t / "missing_folder/log.jsonl";
  try {
    append_run_log(path, {{"type", "train"}, {"step", 1}});
    FAIL() << "appended into a folder that does not exist";
  } catch (const EnvironmentError& e) {
    EXPECT_EQ(e.subject(), path);
    EXPECT_NE(std::string(e.what()).find("cannot write"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(fs::exists(path));
}
