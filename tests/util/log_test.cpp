// The one log (util/log.h): the threshold drops what is below it, a capture sees every line with its
// level and restores what was there, progress lines go through it, and lines written from several
// threads at once arrive whole.
#include <gtest/gtest.h>

#include <sstream>
#include <thread>
#include <vector>

#include "util/log.h"
#include "util/progress.h"

namespace ablenerf {
namespace {

TEST(Log, ThresholdDropsLowerLevelsAndCaptureRestoresIt) {
  set_log_level(LogLevel::Warn);
  {
    LogCapture capture;  // captures everything while it lives
    log_debug("a detail");
    log_warn("a warning");
    EXPECT_EQ(capture.text(), "debug a detail\nwarn a warning\n");
    set_log_level(LogLevel::Warn);
    log_info("dropped");
    log_line(LogLevel::Error, "kept");
    EXPECT_FALSE(capture.contains("dropped"));
    EXPECT_TRUE(capture.contains("error kept"));
    EXPECT_FALSE(log_enabled(LogLevel::Info));
    EXPECT_TRUE(log_enabled(LogLevel::Error));
  }
  EXPECT_EQ(log_level(), LogLevel::Warn);  // the level from before the capture
  set_log_level(LogLevel::Info);
}

TEST(Log, ProgressLinesGoThroughTheLogAndTheLastStays) {
  LogCapture capture;
  Progress p("work", 10, 0.0);
  p.update(5, "x 1", /*force=*/true);
  p.finish("done");
  const std::string text = capture.text();
  EXPECT_NE(text.find("info work 5/10 (50.0%) x 1 elapsed"), std::string::npos) << text;
  EXPECT_NE(text.find("info work 10/10 (100.0%) done elapsed"), std::string::npos) << text;
  // Quiet: no progress at all.
  set_log_level(LogLevel::Warn);
  const size_t before = capture.text().size();
  Progress q("quiet", 4, 0.0);
  q.update(2, "", true);
  q.finish();
  EXPECT_EQ(capture.text().size(), before);
}

TEST(Log, LinesFromManyThreadsArriveWhole) {
  LogCapture capture;
  constexpr int kThreads = 4, kLines = 200;
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t)
    threads.emplace_back([t] {
      for (int i = 0; i < kLines; ++i) log_info("thread " + std::to_string(t) + " line " + std::to_string(i) + " end");
    });
  for (auto& th : threads) th.join();
  std::istringstream in(capture.text());
  std::string line;
  std::vector<int> next(kThreads, 0);
  int count = 0;
  while (std::getline(in, line)) {
    int t = -1, i = -1;
    char tail[8] = {0};
    ASSERT_EQ(std::sscanf(line.c_str(), "info thread %d line %d %3s", &t, &i, tail), 3) << line;
    ASSERT_STREQ(tail, "end") << line;
    EXPECT_EQ(i, next[static_cast<size_t>(t)]++) << "each thread's lines in its order";
    ++count;
  }
  EXPECT_EQ(count, kThreads * kLines);
}

}  // namespace
}  // namespace ablenerf
