#include "util/log.h"

#include <unistd.h>

#include <cstdio>
#include <mutex>

namespace ablenerf {

namespace {

std::mutex& log_mutex() {
  static std::mutex m;
  return m;
}

struct LogState {
  LogLevel level = LogLevel::Info;
  LogSink sink;
  bool progress_open = false;  // the terminal's last line is a progress line without its newline
};

LogState& state() {
  static LogState s;
  return s;
}

// Standard error: progress lines redraw in place on a terminal (carriage return + clear line);
// elsewhere (logs, CI) every line ends with a newline.
void stderr_sink(LogLevel, const std::string& text, bool redraw) {
  static const bool tty = isatty(fileno(stderr)) != 0;
  LogState& s = state();
  if (tty && redraw) {
    std::fprintf(stderr, "\r\033[K%s", text.c_str());
    s.progress_open = true;
  } else {
    // A line after an open progress line takes its place (the progress redraws on its next update).
    std::fprintf(stderr, "%s%s\n", s.progress_open ? "\r\033[K" : "", text.c_str());
    s.progress_open = false;
  }
  std::fflush(stderr);
}

void emit(LogLevel level, const std::string& text, bool redraw) {
  const std::lock_guard<std::mutex> lock(log_mutex());
  LogState& s = state();
  if (level < s.level) return;
  if (s.sink)
    s.sink(level, text, redraw);
  else
    stderr_sink(level, text, redraw);
}

const char* level_name(LogLevel level) {
  switch (level) {
    case LogLevel::Debug: return "debug";
    case LogLevel::Info: return "info";
    case LogLevel::Warn: return "warn";
    case LogLevel::Error: return "error";
  }
  return "?";
}

}  // namespace

void set_log_level(LogLevel level) {
  const std::lock_guard<std::mutex> lock(log_mutex());
  state().level = level;
}

LogLevel log_level() {
  const std::lock_guard<std::mutex> lock(log_mutex());
  return state().level;
}

bool log_enabled(LogLevel level) { return level >= log_level(); }

void set_log_sink(LogSink sink) {
  const std::lock_guard<std::mutex> lock(log_mutex());
  state().sink = std::move(sink);
}

void log_line(LogLevel level, const std::string& text) { emit(level, text, false); }

void log_progress(const std::string& text) { emit(LogLevel::Info, text, true); }

LogCapture::LogCapture() : previous_level_(log_level()) {
  set_log_level(LogLevel::Debug);
  set_log_sink([this](LogLevel level, const std::string& text, bool) {
    lines_ += std::string(level_name(level)) + " " + text + "\n";
  });
}

LogCapture::~LogCapture() {
  set_log_sink({});
  set_log_level(previous_level_);
}

std::string LogCapture::text() const {
  const std::lock_guard<std::mutex> lock(log_mutex());
  return lines_;
}

}  // namespace ablenerf
