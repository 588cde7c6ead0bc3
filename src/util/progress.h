#pragma once
// A progress line for long work: done/total, rate, elapsed, ETA and caller-supplied fields, written
// to the log (util/log.h) at Info level. On a terminal it redraws one line; otherwise (logs, CI) it
// prints a line at most every `min_interval` seconds so that output stays readable.
#include <chrono>
#include <string>

namespace ablenerf {

class Progress {
 public:
  Progress(std::string label, int64_t total, double min_interval_s = 10.0);
  // Reports `done` units finished; `fields` is appended verbatim (e.g. "loss 0.01 psnr 21.3").
  // `fraction` in [0, 1], when given, is how far the work is by another measure (a training run's
  // time budget): the percentage and the ETA then follow it instead of done / total.
  void update(int64_t done, const std::string& fields = "", bool force = false, double fraction = -1);
  void finish(const std::string& fields = "");
  double elapsed_seconds() const;

  static std::string format_duration(double seconds);

 private:
  void report(int64_t done, const std::string& fields, bool force, double fraction, bool last);
  std::string label_;
  int64_t total_, start_done_ = -1;
  double start_fraction_ = -1;
  double min_interval_;
  bool tty_;
  std::chrono::steady_clock::time_point start_, last_print_;
};

}  // namespace ablenerf
