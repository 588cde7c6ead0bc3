// The one atomic writer and the one reader (util/fs.h): binary round trips, replacement without
// leftovers, failures that keep the earlier file and name the file and the fix.
#include <gtest/gtest.h>

#include <cerrno>
#include <cstring>
#include <filesystem>

#include "test_util.h"
#include "util/errors.h"
#include "util/fs.h"

using namespace ablenerf;
namespace fs = std::filesystem;

namespace {

// Every byte value, NULs and a CR/LF among them, longer than one read buffer (64 KiB).
std::string all_bytes(size_t n) {
  std::string s(n, '\0');
  for (size_t i = 0; i < n; ++i) s[i] = static_cast<char>((i * 7 + i / 256) & 0xFF);
  return s;
}

int files_in(const std::string& dir) {
  int n = 0;
  for (const auto& e : fs::directory_iterator(dir)) n += e.is_regular_file() || e.is_directory();
  return n;
}

}  // namespace

TEST(WriteFileAtomic, BinaryRoundTripAndReplacement) {
  test::TempDir t;
  const std::string path = t / "blob.bin";
  const std::string first = all_bytes(200000);
  write_file_atomic(path, first);
  EXPECT_EQ(read_file(path), first);
  EXPECT_EQ(fs::file_size(path), first.size());
  write_file_atomic(path, "short");
  EXPECT_EQ(read_file(path), "short");
  write_file_atomic(path, "");
  EXPECT_EQ(read_file(path), "");
  EXPECT_EQ(files_in(t.path()), 1);  // no temporaries left behind
}

TEST(WriteFileAtomic, FailedWriteKeepsTheEarlierFileAndRemovesTheTemporary) {
  test::TempDir t;
  // A non-empty folder at the target: the temporary is written, the rename fails.
  const std::string path = t / "target";
  fs::create_directories(path);
  test::write_file(path + "/inside.txt", "earlier");
  EXPECT_THROW(write_file_atomic(path, "new"), EnvironmentError);
  EXPECT_EQ(read_file(path + "/inside.txt"), "earlier");
  EXPECT_EQ(files_in(t.path()), 1);  // only the folder: the temporary was removed
}

TEST(WriteFileAtomic, MissingFolderIsAnEnvironmentErrorNamingFileAndFix) {
  test::TempDir t;
  const std::string path = t / "no_such_folder/out.json";
  try {
    write_file_atomic(path, "{}");
    FAIL() << "wrote into a missing folder";
  } catch (const EnvironmentError& e) {
    EXPECT_EQ(e.subject(), path);
    const std::string msg = e.what();
    EXPECT_EQ(msg.rfind(path + ": cannot write: ", 0), 0u) << msg;
    EXPECT_NE(msg.find("the folder " + (t / "no_such_folder") + " does not exist"), std::string::npos) << msg;
  }
}

TEST(WriteError, NamesTheFixForTheCommonCauses) {
  const std::string path = "/runs/a/checkpoint.pt";
  auto msg = [&](int err) { return std::string(write_error(path, err).what()); };
  EXPECT_EQ(msg(ENOSPC), path + ": cannot write: " + std::strerror(ENOSPC) + " (disk full? free space in /runs/a)");
  EXPECT_NE(msg(EDQUOT).find("disk full? free space in /runs/a"), std::string::npos);
  EXPECT_NE(msg(EACCES).find("no permission? make /runs/a writable"), std::string::npos);
  EXPECT_NE(msg(EROFS).find("read-only file system"), std::string::npos);
  EXPECT_NE(msg(EFBIG).find("ulimit -f"), std::string::npos);
  // A bare file name lives in the working folder.
  EXPECT_NE(std::string(write_error("out.png", ENOSPC).what()).find("free space in ."), std::string::npos);
  // No advice: no parenthesis.
  EXPECT_EQ(msg(EIO), path + ": cannot write: " + std::strerror(EIO));
}

TEST(ReadFile, MissingFileAndFolderAreInputErrorsNamingThePath) {
  test::TempDir t;
  for (const std::string& p : {t / "absent.pt", t.path()}) {
    try {
      read_file(p);
      FAIL() << "read " << p;
    } catch (const InputError& e) {
      EXPECT_EQ(e.file(), p);
      EXPECT_NE(std::string(e.what()).find("cannot read"), std::string::npos) << e.what();
    }
  }
}

TEST(EnsureDir, CreatesParentsAndRefusesAFileInTheWay) {
  test::TempDir t;
  ensure_dir(t / "a/b/c");
  EXPECT_TRUE(fs::is_directory(t / "a/b/c"));
  ensure_dir(t / "a/b/c");  // already there: fine
  test::write_file(t / "file", "x");
  try {
    ensure_dir(t / "file/sub");
    FAIL() << "created a folder under a file";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("is a file"), std::string::npos) << e.what();
  }
}
