#pragma once
// A one-line progress report with rate-based ETA on stderr, for long renders and evaluations.
// On a terminal the line is redrawn in place; otherwise a line is printed at most every
// few seconds (and at the end) so that logs stay short.
#include <chrono>
#include <cstdint>
#include <string>

namespace ablenerf {

class ProgressLine {
 public:
  // `label` prefixes the line, `total` is the amount of work (any unit), `unit` names it.
  ProgressLine(std::string label, int64_t total, std::string unit);
  // Reports `done` units of work completed so far (monotone); `note` is appended.
  void update(int64_t done, const std::string& note = "");
  // Prints the final state and a newline.
  void finish(const std::string& note = "");
  // "1h02m", "3m05s", "12s": compact durations for the line.
  static std::string format_duration(double seconds);

 private:
  void print(int64_t done, const std::string& note, bool final);
  std::string label_, unit_;
  int64_t total_;
  bool tty_;
  std::chrono::steady_clock::time_point start_, last_print_;
  bool printed_ = false;
};

}  // namespace ablenerf
