#include "eval/progress.h"

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <iostream>
#include <sstream>

namespace ablenerf {
namespace {
// Seconds between printed lines when stderr is not a terminal (keeps CI logs short).
constexpr double kLogIntervalS = 5.0;
// Seconds between redraws on a terminal.
constexpr double kTtyIntervalS = 0.2;
constexpr int kBarWidth = 24;
}  // namespace

ProgressLine::ProgressLine(std::string label, int64_t total, std::string unit)
    : label_(std::move(label)), unit_(std::move(unit)), total_(total), tty_(::isatty(STDERR_FILENO) != 0) {
  start_ = last_print_ = std::chrono::steady_clock::now();
}

std::string ProgressLine::format_duration(double s) {
  if (!std::isfinite(s) || s < 0) return "?";
  const auto total = static_cast<int64_t>(std::llround(s));
  const int64_t h = total / 3600, m = (total % 3600) / 60, sec = total % 60;
  char buf[32];
  if (h > 0)
    std::snprintf(buf, sizeof buf, "%lldh%02lldm", static_cast<long long>(h), static_cast<long long>(m));
  else if (m > 0)
    std::snprintf(buf, sizeof buf, "%lldm%02llds", static_cast<long long>(m), static_cast<long long>(sec));
  else
    std::snprintf(buf, sizeof buf, "%llds", static_cast<long long>(sec));
  return buf;
}

void ProgressLine::update(int64_t done, const std::string& note) {
  const auto now = std::chrono::steady_clock::now();
  const double since = std::chrono::duration<double>(now - last_print_).count();
  if (printed_ && since < (tty_ ? kTtyIntervalS : kLogIntervalS)) return;
  last_print_ = now;
  print(done, note, false);
}

void ProgressLine::finish(const std::string& note) { print(total_, note, true); }

void ProgressLine::print(int64_t done, const std::string& note, bool final) {
  printed_ = true;
  const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  const double frac = total_ > 0 ? static_cast<double>(done) / static_cast<double>(total_) : 1.0;
  // ETA from the average rate so far: remaining work / (done / elapsed).
  const double eta = done > 0 ? elapsed * static_cast<double>(total_ - done) / static_cast<double>(done) : NAN;
  std::ostringstream line;
  line << label_ << " [";
  const int filled = static_cast<int>(frac * kBarWidth);
  for (int i = 0; i < kBarWidth; ++i) line << (i < filled ? '#' : '.');
  line << "] " << done << "/" << total_ << " " << unit_ << "  elapsed " << format_duration(elapsed);
  if (!final) line << "  ETA " << format_duration(eta);
  if (!note.empty()) line << "  " << note;
  if (tty_)
    std::cerr << "\r\033[K" << line.str() << (final ? "\n" : "") << std::flush;
  else
    std::cerr << line.str() << std::endl;
}

}  // namespace ablenerf
