#include "util/fs.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <limits>

namespace fs = std::filesystem;

namespace ablenerf {

namespace {

// The folder a file lives in, for messages ("." for a bare name).
std::string folder_of(const std::string& path) {
  const fs::path parent = fs::path(path).parent_path();
  return parent.empty() ? std::string(".") : parent.string();
}

// Flushes a file (or folder) to the device. Returns 0 or the errno of the failure: on some file
// systems (NFS, quota, thin provisioning) a full disk only shows up here, not in write().
int fsync_path(const std::string& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return errno;
  const int err = ::fsync(fd) == 0 ? 0 : errno;
  if (::close(fd) != 0 && err == 0) return errno;
  return err;
}

// Writes all of `bytes` to `fd`, flushes it and closes it. Returns 0 or the first errno; the
// descriptor is closed either way.
int write_and_close(int fd, std::string_view bytes) {
  int err = 0;
  size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0) {
      if (errno == EINTR) continue;
      err = errno;
      break;
    }
    done += static_cast<size_t>(n);
  }
  if (err == 0 && ::fsync(fd) != 0) err = errno;
  if (::close(fd) != 0 && err == 0) err = errno;
  return err;
}

// What to do about a failed write (errno `err`) into the folder `dir`; "" when there is no advice.
std::string fix_for(int err, const std::string& dir) {
  switch (err) {
    case ENOSPC:
    case EDQUOT: return "disk full? free space in " + dir;
    case EFBIG:
      return "file too large for the file system or the file-size limit (ulimit -f): free space in " + dir +
             " or raise the limit";
    case EACCES:
    case EPERM: return "no permission? make " + dir + " writable or write elsewhere";
    case EROFS: return "read-only file system: write elsewhere";
    case ENOENT: return "the folder " + dir + " does not exist";
    default: return "";
  }
}

}  // namespace

EnvironmentError write_error(const std::string& path, int err) {
  return EnvironmentError(path, std::string("cannot write: ") + std::strerror(err), fix_for(err, folder_of(path)));
}

std::string atomic_temp_prefix(const std::string& path) { return path + ".tmp"; }

void write_file_atomic(const std::string& path, std::string_view bytes) {
  static std::atomic<unsigned> counter{0};
  const std::string tmp = atomic_temp_prefix(path) + std::to_string(::getpid()) + "_" + std::to_string(counter++);
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
  if (fd < 0) throw write_error(path, errno);
  int err = write_and_close(fd, bytes);
  if (err == 0 && ::rename(tmp.c_str(), path.c_str()) != 0) err = errno;
  if (err != 0) {
    ::unlink(tmp.c_str());
    throw write_error(path, err);
  }
  // Makes the rename durable; failures are ignored because some file systems cannot fsync a folder
  // and the new file is already complete either way.
  (void)fsync_path(folder_of(path));
}

int open_for_reading(const std::string& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw InputError(path, "", std::string("cannot read: ") + std::strerror(errno));
  struct stat st {};
  if (::fstat(fd, &st) == 0 && S_ISDIR(st.st_mode)) {
    ::close(fd);
    throw InputError(path, "", "cannot read: a folder, not a file");
  }
  return fd;
}

std::string read_file_prefix(const std::string& path, size_t max_bytes) {
  const int fd = open_for_reading(path);
  std::string out;
  struct stat st {};
  if (::fstat(fd, &st) == 0 && S_ISREG(st.st_mode) && st.st_size > 0)
    out.reserve(std::min(static_cast<size_t>(st.st_size), max_bytes));
  char buf[1 << 16];
  while (out.size() < max_bytes) {
    const ssize_t n = ::read(fd, buf, std::min(sizeof buf, max_bytes - out.size()));
    if (n == 0) break;
    if (n < 0) {
      if (errno == EINTR) continue;
      const int err = errno;
      ::close(fd);
      throw InputError(path, "", std::string("cannot read: ") + std::strerror(err));
    }
    out.append(buf, static_cast<size_t>(n));
  }
  ::close(fd);
  return out;
}

std::string read_file(const std::string& path) { return read_file_prefix(path, std::numeric_limits<size_t>::max()); }

void ensure_dir(const std::string& path) {
  std::error_code ec;
  fs::create_directories(path, ec);
  if (!ec) return;
  std::error_code ignored;
  // A file where a folder should be: the path given is wrong, not the machine.
  for (fs::path p = fs::path(path); !p.empty(); p = p.parent_path()) {
    if (fs::exists(p, ignored) && !fs::is_directory(p, ignored))
      throw InputError(path, "", "cannot create the folder: " + p.string() + " is a file");
    if (p == p.parent_path()) break;
  }
  throw EnvironmentError(path, "cannot create the folder: " + ec.message(), fix_for(ec.value(), folder_of(path)));
}

}  // namespace ablenerf
