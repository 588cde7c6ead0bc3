// Damaged or foreign checkpoints through the CLI: `train --resume` exits 2 with one line naming
// the problem (checksum, length, version, the differing config key) and never loads or
// overwrites the checkpoint.
#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>
#include <fstream>

#include "reliability/reliability_util.h"
#include "test_util.h"

using namespace ablenerf;
namespace fs = std::filesystem;

namespace {

// Header layout of checkpoint.h: magic (8) | u32 version | u64 payload bytes | u64 FNV-1a.
constexpr size_t kVersionOffset = 8;
constexpr size_t kHeaderBytes = 8 + 4 + 8 + 8;

std::string args_string(const std::vector<std::string>& v) {
  std::string s;
  for (const auto& a : v) s += " '" + a + "'";
  return s;
}

class DamagedCheckpoint : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new test::TempDir("ablenerf_ckpt_cli");
    auto s = test::run_cli("synth --out " + (*dir_ / "data") + " --res 16 --train-views 2 --test-views 1");
    ASSERT_EQ(s.exit_code, 0) << s.output;
    auto r = test::run_cli(train("run", false) + " --set train.steps=3");
    ASSERT_EQ(r.exit_code, 0) << r.output;
    good_ = test::read_text(*dir_ / "run/checkpoint.pt");
    ASSERT_GT(good_.size(), kHeaderBytes);
  }
  static void TearDownTestSuite() {
    delete dir_;
    dir_ = nullptr;
  }
  static std::string train(const std::string& run, bool resume) {
    return "train --data " + (*dir_ / "data") + " --out " + (*dir_ / run) + (resume ? " --resume" : "") +
           args_string(test::tiny_train_args());
  }
  // Writes `bytes` as the run's checkpoint, resumes to step 6, and checks the refusal.
  static test::CommandResult resume_with(const std::string& bytes, const std::string& extra = "") {
    const std::string path = *dir_ / "run/checkpoint.pt";
    {
      std::ofstream out(path, std::ios::binary | std::ios::trunc);
      out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    }
    auto r = test::run_cli(train("run", true) + " --set train.steps=6" + extra);
    EXPECT_EQ(test::read_text(path), bytes) << "a refused checkpoint must not be overwritten";
    return r;
  }
  static test::TempDir* dir_;
  static std::string good_;
};
test::TempDir* DamagedCheckpoint::dir_ = nullptr;
std::string DamagedCheckpoint::good_;

// The error is the last line, "error: FILE: FIELD: what".
bool one_error_line_containing(const std::string& out, const std::string& word) {
  const auto pos = out.find("error: ");
  return pos != std::string::npos && out.find(word, pos) != std::string::npos &&
         out.find('\n', pos) >= out.find(word, pos) && out.find("error: ", pos + 1) == std::string::npos;
}

TEST_F(DamagedCheckpoint, FlippedPayloadByteIsAChecksumError) {
  std::string bad = good_;
  bad[kHeaderBytes + (bad.size() - kHeaderBytes) / 2] ^= 0x01;
  const auto r = resume_with(bad);
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_TRUE(one_error_line_containing(r.output, "checksum")) << r.output;
}

TEST_F(DamagedCheckpoint, TruncatedFileIsReported) {
  const auto r = resume_with(good_.substr(0, good_.size() - 1000));
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_TRUE(one_error_line_containing(r.output, "truncated")) << r.output;
  const auto h = resume_with(good_.substr(0, kHeaderBytes / 2));  // not even a whole header
  EXPECT_EQ(h.exit_code, 2) << h.output;
  EXPECT_TRUE(one_error_line_containing(h.output, "truncated")) << h.output;
}

TEST_F(DamagedCheckpoint, OtherFormatVersionIsNamed) {
  std::string bad = good_;
  const uint32_t future = 99;
  std::memcpy(&bad[kVersionOffset], &future, sizeof(future));
  const auto r = resume_with(bad);
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_TRUE(one_error_line_containing(r.output, "version")) << r.output;
  EXPECT_NE(r.output.find("99"), std::string::npos) << r.output;
}

TEST_F(DamagedCheckpoint, OtherModelConfigNamesTheKey) {
  const auto r = resume_with(good_, " --set model.width=32");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_TRUE(one_error_line_containing(r.output, "model.width")) << r.output;
}

TEST_F(DamagedCheckpoint, IntactCheckpointResumes) {
  // Control: the same command on the undamaged bytes resumes and reaches step 6.
  const std::string path = *dir_ / "run/checkpoint.pt";
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(good_.data(), static_cast<std::streamsize>(good_.size()));
  }
  auto r = test::run_cli(train("run", true) + " --set train.steps=6");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("at step 3"), std::string::npos) << r.output;
}

}  // namespace
