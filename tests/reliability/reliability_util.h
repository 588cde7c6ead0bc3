#pragma once
// Helpers of the reliability suite: the tiny training command line and a child process that can
// be SIGKILLed at a chosen moment.
#include <sys/types.h>

#include <string>
#include <vector>

namespace ablenerf::test {

// --set list of a model and run small enough to train a step in ~0.1 s on one core.
std::vector<std::string> tiny_train_args();

// A child running $ABLENERF_BIN with `args`, OMP_NUM_THREADS=1 (bit-reproducible), output
// appended to `log_path`.
class ChildProcess {
 public:
  ChildProcess(const std::vector<std::string>& args, const std::string& log_path);
  ~ChildProcess();
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;

  // True (and the exit status stored) once the child has ended; never blocks.
  bool finished();
  // SIGKILL and reap. Returns false if the child had already ended on its own.
  bool kill9();
  // Sends `sig` without waiting. Returns false if the child had already ended.
  bool send_signal(int sig);
  // Blocks until the child ends; returns its exit code (128+signal when killed).
  int wait();
  int exit_code() const { return exit_code_; }

 private:
  pid_t pid_ = -1;
  int exit_code_ = -1;
};

// The whole file, or "" when it cannot be read (for failure messages).
std::string read_text(const std::string& path);

// Names of the files in `dir` (not recursive); empty when it does not exist.
std::vector<std::string> list_dir(const std::string& dir);

}  // namespace ablenerf::test
