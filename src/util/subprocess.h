#pragma once
// Running another program (COLMAP, ffprobe) with its output appended to a log file: argv is passed
// as is, no shell in between, so file names need no quoting.
#include <string>
#include <utility>
#include <vector>

namespace ablenerf {

// Whether `program` (a name looked up on PATH, or a path) can be executed.
bool program_available(const std::string& program);

// Runs argv[0] (looked up on PATH) with argv, stdin from /dev/null, stdout and stderr appended to
// `log_path`, the extra environment variables `env` set for it alone; waits and returns its exit
// status (128 + N when killed by signal N). EnvironmentError when it cannot be started (not
// installed, the log not writable).
int run_logged(const std::vector<std::string>& argv, const std::string& log_path,
               const std::vector<std::pair<std::string, std::string>>& env = {});

// The same with stdout captured and returned (stderr to the log); the exit status in *status.
std::string run_captured(const std::vector<std::string>& argv, const std::string& log_path, int* status);

}  // namespace ablenerf
