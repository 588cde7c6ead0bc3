#include "reliability/reliability_util.h"

#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace fs = std::filesystem;

namespace ablenerf::test {

std::vector<std::string> tiny_train_args() {
  std::vector<std::string> out;
  for (const char* kv :
       {"model.width=16", "model.heads=1", "model.ff_ratio=1", "model.coarse_layers=1", "model.fine_layers=1",
        "model.samples=8", "model.le_count=2", "model.le_layers=1", "train.rays_per_step=64", "train.micro_batch=64",
        "train.eval_every=0", "train.log_every=1", "train.lr_warmup_steps=2", "train.lr_decay_steps=0"}) {
    out.push_back("--set");
    out.push_back(kv);
  }
  out.push_back("--device");
  out.push_back("cpu");
  return out;
}

ChildProcess::ChildProcess(const std::vector<std::string>& args, const std::string& log_path) {
  const char* bin = std::getenv("ABLENERF_BIN");
  if (!bin) throw std::runtime_error("ABLENERF_BIN is not set (run the tests through ctest)");
  std::vector<std::string> argv_s{bin};
  argv_s.insert(argv_s.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& s : argv_s) argv.push_back(s.data());
  argv.push_back(nullptr);
  pid_ = ::fork();
  if (pid_ < 0) throw std::runtime_error("fork failed");
  if (pid_ == 0) {
    // Child: only async-signal-safe calls until exec.
    const int fd = ::open(log_path.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
    if (fd >= 0) {
      ::dup2(fd, 1);
      ::dup2(fd, 2);
    }
    ::setenv("OMP_NUM_THREADS", "1", 1);
    ::execv(argv[0], argv.data());
    ::_exit(127);
  }
}

ChildProcess::~ChildProcess() {
  if (pid_ > 0) kill9();
}

bool ChildProcess::finished() {
  if (pid_ <= 0) return true;
  int status = 0;
  const pid_t r = ::waitpid(pid_, &status, WNOHANG);
  if (r == 0) return false;
  exit_code_ = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  pid_ = -1;
  return true;
}

bool ChildProcess::kill9() {
  if (finished()) return false;
  ::kill(pid_, SIGKILL);
  wait();
  return true;
}

bool ChildProcess::send_signal(int sig) {
  if (finished()) return false;
  ::kill(pid_, sig);
  return true;
}

int ChildProcess::wait() {
  if (pid_ > 0) {
    int status = 0;
    ::waitpid(pid_, &status, 0);
    exit_code_ = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
    pid_ = -1;
  }
  return exit_code_;
}

std::string read_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::vector<std::string> list_dir(const std::string& dir) {
  std::vector<std::string> out;
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec))
    out.push_back(it->path().filename().string());
  return out;
}

}  // namespace ablenerf::test
