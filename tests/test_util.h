#pragma once
// Helpers shared by the test suites: scratch folders, the shared data folder, running the CLI.
#include <string>

namespace ablenerf::test {

// A fresh empty folder under the system temp dir, removed when the object dies.
class TempDir {
 public:
  explicit TempDir(const std::string& tag = "ablenerf");
  ~TempDir();
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const std::string& path() const { return path_; }
  std::string operator/(const std::string& name) const { return path_ + "/" + name; }

 private:
  std::string path_;
};

// The repository root (compile-time, overridable by $ABLENERF_SOURCE_DIR).
std::string source_dir();

// ../shared/data/nerf_synthetic/lego beside the repository, or "" when it is absent.
std::string lego_dir();

// ../shared/weights beside the repository, or "" when absent.
std::string shared_weights_dir();

struct CommandResult {
  int exit_code = -1;
  std::string output;  // stdout and stderr together
};

// Runs the built CLI ($ABLENERF_BIN) with the given argument string through /bin/sh.
CommandResult run_cli(const std::string& args);

// Writes a text file (creating parent folders).
void write_file(const std::string& path, const std::string& text);

// LibTorch's intra-op thread count set to `threads` for the scope, restored afterwards. The CPU
// ray split takes the larger of this count and OpenBLAS's, so 2 makes it split on any machine.
class IntraOpThreads {
 public:
  explicit IntraOpThreads(int threads);
  ~IntraOpThreads();
  IntraOpThreads(const IntraOpThreads&) = delete;
  IntraOpThreads& operator=(const IntraOpThreads&) = delete;

 private:
  int previous_;
};

}  // namespace ablenerf::test
