#include "util/progress.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "util/log.h"

namespace ablenerf {

Progress::Progress(std::string label, int64_t total, double min_interval_s)
    : label_(std::move(label)),
      total_(total),
      min_interval_(min_interval_s),
      tty_(::isatty(STDERR_FILENO) != 0),
      start_(std::chrono::steady_clock::now()),
      last_print_(start_) {}

double Progress::elapsed_seconds() const {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
}

std::string Progress::format_duration(double s) {
  if (!std::isfinite(s) || s < 0) return "?";
  const long t = std::lround(s);
  char buf[32];
  if (t >= 3600)
    std::snprintf(buf, sizeof buf, "%ldh%02ldm", t / 3600, (t / 60) % 60);
  else
    std::snprintf(buf, sizeof buf, "%ldm%02lds", t / 60, t % 60);
  return buf;
}

void Progress::update(int64_t done, const std::string& fields, bool force, double fraction) {
  report(done, fields, force, fraction, /*last=*/false);
}

void Progress::report(int64_t done, const std::string& fields, bool force, double fraction, bool last) {
  if (start_done_ < 0) start_done_ = done;  // a resumed run starts counting from where it is
  if (fraction >= 0 && start_fraction_ < 0) start_fraction_ = fraction;
  const auto now = std::chrono::steady_clock::now();
  const double since = std::chrono::duration<double>(now - last_print_).count();
  const double interval = tty_ ? 0.25 : min_interval_;
  if (!force && since < interval && done < total_) return;
  last_print_ = now;
  const double el = elapsed_seconds();
  const double rate = el > 0 ? static_cast<double>(done - start_done_) / el : 0.0;
  double eta = rate > 0 ? static_cast<double>(total_ - done) / rate : NAN;
  double pct = total_ > 0 ? 100.0 * static_cast<double>(done) / static_cast<double>(total_) : 100.0;
  if (fraction >= 0) {
    const double f = std::min(fraction, 1.0);
    const double frate = el > 0 ? (f - start_fraction_) / el : 0.0;
    pct = 100.0 * f;
    eta = frate > 0 ? (1.0 - f) / frate : NAN;
  }
  char head[160];
  std::snprintf(head, sizeof head, "%s %lld/%lld (%.1f%%) ", label_.c_str(), static_cast<long long>(done),
                static_cast<long long>(total_), pct);
  const std::string text = head + fields + " elapsed " + format_duration(el) + " ETA " + format_duration(eta);
  // The last report stays on screen as an ordinary line; the others redraw in place on a terminal.
  if (last)
    log_info(text);
  else
    log_progress(text);
}

void Progress::finish(const std::string& fields) { report(total_, fields, true, -1, /*last=*/true); }

}  // namespace ablenerf
