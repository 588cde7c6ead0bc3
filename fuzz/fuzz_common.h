#pragma once
// Shared scaffolding of the libFuzzer targets: one scratch folder per fuzzing process and a
// helper that writes the fuzzer's bytes to a file in it.
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>

namespace ablenerf::fuzz {

// A folder under $TMPDIR named after the process id, so parallel fuzz jobs never share files.
// Removed at exit (libFuzzer exits through exit(), which runs atexit handlers). The name lives on
// the heap and is never destroyed, so the exit handler can still read it.
inline const std::string& scratch_dir() {
  static const std::string* const dir = [] {
    const auto p = std::filesystem::temp_directory_path() / ("ablenerf_fuzz_" + std::to_string(::getpid()));
    std::filesystem::create_directories(p);
    auto* name = new std::string(p.string());
    std::atexit([] {
      std::error_code ec;
      std::filesystem::remove_all(*dir, ec);
    });
    return name;
  }();
  return *dir;
}

// Writes exactly `size` bytes to `path` (replacing it); aborts if the scratch disk fails, since a
// fuzz run on a short file would silently test something else.
inline void write_bytes(const std::string& path, const uint8_t* data, size_t size) {
  FILE* f = std::fopen(path.c_str(), "wb");
  if (!f || (size > 0 && std::fwrite(data, 1, size, f) != size) || std::fclose(f) != 0) {
    std::perror(path.c_str());
    std::abort();
  }
}

}  // namespace ablenerf::fuzz
