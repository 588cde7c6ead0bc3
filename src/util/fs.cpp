#include "util/fs.h"

#include <fcntl.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "util/errors.h"

namespace fs = std::filesystem;

namespace ablenerf {

namespace {
// Flushes a file (or folder) to the device. Returns 0 or the errno of the failure: on some file
// systems (NFS, quota, thin provisioning) a full disk only shows up here, not in write().
int fsync_path(const std::string& path) {
  int fd = ::open(path.c_str(), O_RDONLY);
  if (fd < 0) return errno;
  const int rc = ::fsync(fd);
  const int err = rc == 0 ? 0 : errno;
  if (::close(fd) != 0 && err == 0) return errno;
  return err;
}
}  // namespace

void atomic_write(const std::string& path, const std::function<void(const std::string&)>& writer) {
  static std::atomic<unsigned> counter{0};
  const std::string tmp = path + ".tmp" + std::to_string(::getpid()) + "_" + std::to_string(counter++);
  try {
    writer(tmp);
    if (const int err = fsync_path(tmp))
      throw InputError(path, "", std::string("cannot write: ") + std::strerror(err));
  } catch (...) {
    std::error_code ec;
    fs::remove(tmp, ec);
    throw;
  }
  std::error_code ec;
  fs::rename(tmp, path, ec);
  if (ec) {
    fs::remove(tmp, ec);
    throw InputError(path, "", "cannot write: rename failed: " + ec.message());
  }
  // Makes the rename durable; failures are ignored because some file systems cannot fsync a folder
  // and the new file is already complete either way.
  const fs::path parent = fs::path(path).parent_path();
  (void)fsync_path(parent.empty() ? "." : parent.string());
}

void atomic_write_text(const std::string& path, const std::string& text) {
  atomic_write(path, [&](const std::string& tmp) {
    std::ofstream out(tmp, std::ios::binary);
    out.write(text.data(), static_cast<std::streamsize>(text.size()));
    out.close();  // close() flushes; a full disk surfaces here at the latest
    if (!out) throw InputError(path, "", std::string("cannot write: ") + std::strerror(errno));
  });
}

std::string read_text_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path, "", std::string("cannot read: ") + std::strerror(errno));
  std::ostringstream ss;
  ss << in.rdbuf();
  if (in.bad()) throw InputError(path, "", "read error");
  return ss.str();
}

void ensure_dir(const std::string& path) {
  std::error_code ec;
  fs::create_directories(path, ec);
  if (ec) throw InputError(path, "", "cannot create directory: " + ec.message());
}

}  // namespace ablenerf
