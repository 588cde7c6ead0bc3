#include "test_util.h"

#include <gtest/gtest.h>

#include <ATen/CPUGeneratorImpl.h>
#include <ATen/Parallel.h>

#include <ftw.h>
#include <sys/stat.h>
#include <sys/wait.h>

#include <array>
#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <stdexcept>

#include "util/errors.h"

namespace fs = std::filesystem;

namespace ablenerf::test {

TempDir::TempDir(const std::string& tag) {
  std::random_device rd;
  for (int attempt = 0; attempt < 100; ++attempt) {
    const fs::path p = fs::temp_directory_path() / (tag + "_" + std::to_string(rd()));
    std::error_code ec;
    if (fs::create_directory(p, ec)) {
      path_ = p.string();
      return;
    }
  }
  throw std::runtime_error("cannot create a temporary folder");
}

namespace {
int remove_entry(const char* path, const struct stat*, int, struct FTW*) { return ::remove(path); }
}  // namespace

TempDir::~TempDir() {
  // POSIX nftw, children first, links not followed. Not std::filesystem::remove_all: on the GPU
  // machine (PyTorch 2.11's LibTorch, g++ 13) tests crashed when a temporary folder was removed at
  // their end (no backtrace was taken; docs/GPU.md), and this avoids the libstdc++ call.
  if (!path_.empty()) ::nftw(path_.c_str(), remove_entry, 16, FTW_DEPTH | FTW_PHYS);
}

std::string source_dir() {
  if (const char* s = std::getenv("ABLENERF_SOURCE_DIR")) return s;
  return ABLENERF_SOURCE_DIR;
}

std::string lego_dir() {
  const fs::path p = fs::path(source_dir()) / ".." / "shared" / "data" / "nerf_synthetic" / "lego";
  return fs::exists(p / "transforms_train.json") ? p.string() : std::string();
}

std::string shared_weights_dir() {
  const fs::path p = fs::path(source_dir()) / ".." / "shared" / "weights";
  return fs::exists(p) ? p.string() : std::string();
}

ScopedEnv::ScopedEnv(const char* name, const std::string& value) : name_(name) {
  if (const char* was = std::getenv(name)) previous_ = was;
  ::setenv(name, value.c_str(), 1);
}

ScopedEnv::~ScopedEnv() {
  if (previous_)
    ::setenv(name_, previous_->c_str(), 1);
  else
    ::unsetenv(name_);
}

CommandResult run_cli(const std::string& args) {
  const char* bin = std::getenv("ABLENERF_BIN");
  if (!bin) throw std::runtime_error("ABLENERF_BIN is not set (run the tests through ctest)");
  const std::string cmd = std::string(bin) + " " + args + " 2>&1";
  CommandResult r;
  FILE* pipe = ::popen(cmd.c_str(), "r");
  if (!pipe) throw std::runtime_error("popen failed");
  std::array<char, 4096> buf{};
  size_t n;
  while ((n = std::fread(buf.data(), 1, buf.size(), pipe)) > 0) r.output.append(buf.data(), n);
  const int status = ::pclose(pipe);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  return r;
}

void write_file(const std::string& path, const std::string& text) {
  fs::create_directories(fs::path(path).parent_path());
  std::ofstream out(path, std::ios::binary);
  out << text;
  if (!out) throw std::runtime_error("cannot write " + path);
}

IntraOpThreads::IntraOpThreads(int threads) : previous_(at::get_num_threads()) {
  at::set_num_threads(threads);
  if (threads == 1) single_blas_.emplace();
}
IntraOpThreads::~IntraOpThreads() {
  single_blas_.reset();
  at::set_num_threads(previous_);
}

Rays random_rays(int64_t n, uint64_t seed, torch::Dtype dtype) {
  torch::Generator gen = at::detail::createCPUGenerator(seed);
  const auto opts = torch::TensorOptions().dtype(dtype);
  const auto o = torch::randn({n, 3}, gen, opts) * 0.2 + torch::tensor({0.0, 0.0, 4.0}, opts);
  const auto d = torch::randn({n, 3}, gen, opts) * 0.2 + torch::tensor({0.0, 0.0, -1.0}, opts);
  return {o, d, torch::full({n, 1}, kBlenderPixelRadius, opts)};
}

void expect_input_error(const std::function<void()>& f, const std::string& file, const std::string& field,
                        const std::string& what, bool exact_field) {
  try {
    f();
    ADD_FAILURE() << "expected an InputError for " << file << ": " << field << ": " << what;
  } catch (const InputError& e) {
    EXPECT_EQ(e.file(), file) << e.what();
    if (exact_field)
      EXPECT_EQ(e.field(), field) << e.what();
    else
      EXPECT_NE(e.field().find(field), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
    EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos) << "one line: " << e.what();
  }
}

std::string npy_file(const std::string& dict, const std::string& data, int major) {
  const size_t prefix = 6 + 2 + (major == 1 ? 2 : 4);
  std::string header = dict;
  while ((prefix + header.size() + 1) % 64 != 0) header += ' ';
  header += '\n';
  std::string out = "\x93NUMPY";
  out += static_cast<char>(major);
  out += '\0';
  const size_t len = header.size();
  for (size_t k = 0; k < (major == 1 ? 2u : 4u); ++k) out += static_cast<char>((len >> (8 * k)) & 0xff);
  return out + header + data;
}

std::string llff_poses_bounds_npy(const std::vector<double>& rows) {
  if (rows.size() % 17 != 0) throw std::invalid_argument("llff_poses_bounds_npy: not rows of 17 numbers");
  return npy_file("{'descr': '<f8', 'fortran_order': False, 'shape': (" + std::to_string(rows.size() / 17) + ", 17), }",
                  std::string(reinterpret_cast<const char*>(rows.data()), rows.size() * sizeof(double)));
}

}  // namespace ablenerf::test
