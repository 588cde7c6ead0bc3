#pragma once
// The project's one log: every line that library code shows a user goes through here, with a
// level, to one sink (standard error by default; a test or an embedding program installs its own).
// The CLI sets the threshold from --quiet / --verbose (every command has both); errors that end a
// command are printed by main() itself.
//
// Why not spdlog (Debian's libspdlog-dev): what is needed is a threshold, a replaceable sink and a
// progress line that redraws in place on a terminal; the GPU machines build without a package
// registry, so spdlog and its fmt would have to travel with every build for these ~80 lines.
#include <functional>
#include <string>

namespace ablenerf {

enum class LogLevel { Debug = 0, Info = 1, Warn = 2, Error = 3 };

// Lines below `level` are dropped. Default: Info. --quiet = Warn, --verbose = Debug.
void set_log_level(LogLevel level);
LogLevel log_level();
bool log_enabled(LogLevel level);

// Where lines go: (level, text without a trailing newline, redraw). `redraw` marks a progress line
// that a terminal sink may draw over the previous one. An empty function restores standard error.
using LogSink = std::function<void(LogLevel, const std::string&, bool redraw)>;
void set_log_sink(LogSink sink);

// One line at `level` (thread-safe: lines from several threads never interleave).
void log_line(LogLevel level, const std::string& text);
inline void log_debug(const std::string& text) { log_line(LogLevel::Debug, text); }
inline void log_info(const std::string& text) { log_line(LogLevel::Info, text); }
inline void log_warn(const std::string& text) { log_line(LogLevel::Warn, text); }
// A progress line at Info level: on a terminal it replaces the previous progress line.
void log_progress(const std::string& text);

// Collects every line logged while it lives (whatever the threshold), for tests; restores the
// previous sink and threshold on destruction.
class LogCapture {
 public:
  LogCapture();
  ~LogCapture();
  LogCapture(const LogCapture&) = delete;
  LogCapture& operator=(const LogCapture&) = delete;
  // Everything captured, one line each, "LEVEL text" (LEVEL: debug, info, warn, error).
  std::string text() const;
  bool contains(const std::string& part) const { return text().find(part) != std::string::npos; }

 private:
  std::string lines_;
  LogLevel previous_level_;
};

}  // namespace ablenerf
