// Resource limits: a full disk while writing outputs (PNG, text, checkpoint, a training run) fails
// with an EnvironmentError naming the file and the fix (exit code 1 from the CLI) and leaves the
// earlier file at that path intact; a dataset too large for memory is refused before any image is
// decoded, with the size it needed.
//
// The small disk is a 1 MiB tmpfs when this process may mount one (root), else the file-size
// rlimit (writes past it fail with EFBIG; SIGXFSZ is ignored meanwhile).
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/mount.h>
#include <sys/resource.h>
#include <torch/torch.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "data/dataset.h"
#include "model/able_nerf.h"
#include "reliability/reliability_util.h"
#include "run/run_folder.h"
#include "test_util.h"
#include "train/checkpoint.h"
#include "util/errors.h"
#include "util/fs.h"
#include "util/image_io.h"
#include "model/model_config.h"

using namespace ablenerf;
namespace fs = std::filesystem;

namespace {

constexpr int64_t kCapacity = int64_t(1) << 20;  // 1 MiB: small outputs fit, big ones do not
constexpr int64_t kTooBig = 2 * kCapacity;

// A folder where writing more than kCapacity bytes fails, for the lifetime of the object.
class SmallDisk {
 public:
  SmallDisk() : tmp_("ablenerf_small_disk") {
    dir_ = tmp_ / "disk";
    fs::create_directories(dir_);
    const std::string opts = "size=" + std::to_string(kCapacity);
    if (::geteuid() == 0 && ::mount("tmpfs", dir_.c_str(), "tmpfs", 0, opts.c_str()) == 0) {
      mounted_ = true;
      return;
    }
    ::getrlimit(RLIMIT_FSIZE, &old_);
    rlimit small = old_;
    small.rlim_cur = static_cast<rlim_t>(kCapacity);
    old_handler_ = ::signal(SIGXFSZ, SIG_IGN);
    ::setrlimit(RLIMIT_FSIZE, &small);
  }
  ~SmallDisk() {
    if (mounted_) {
      ::umount(dir_.c_str());
    } else {
      ::setrlimit(RLIMIT_FSIZE, &old_);
      ::signal(SIGXFSZ, old_handler_);
    }
  }
  bool is_tmpfs() const { return mounted_; }
  const std::string& dir() const { return dir_; }
  // What the failure message must advise: a full tmpfs is ENOSPC, the rlimit EFBIG.
  std::string expected_fix() const { return mounted_ ? "disk full? free space in " + dir_ : "ulimit -f"; }
  std::string operator/(const std::string& name) const { return dir_ + "/" + name; }
  // Files whose name says they are temporaries of write_file_atomic.
  int leftover_temporaries() const {
    int n = 0;
    for (const auto& f : test::list_dir(dir_)) n += f.find(".tmp") != std::string::npos;
    return n;
  }

 private:
  test::TempDir tmp_;
  std::string dir_;
  bool mounted_ = false;
  rlimit old_{};
  sighandler_t old_handler_ = SIG_DFL;
};

// Runs `f`, which must throw EnvironmentError naming `path` and the disk's fix; returns the message.
template <typename F>
std::string expect_write_failure(F&& f, const std::string& path, const SmallDisk& disk) {
  try {
    f();
  } catch (const EnvironmentError& e) {
    const std::string msg = e.what();
    EXPECT_EQ(e.subject(), path) << msg;
    EXPECT_EQ(msg.rfind(path + ": cannot write: ", 0), 0u) << msg;
    EXPECT_NE(msg.find(disk.expected_fix()), std::string::npos) << msg;
    return msg;
  } catch (const std::exception& e) {
    ADD_FAILURE() << "not an EnvironmentError: " << e.what();
    return "";
  }
  ADD_FAILURE() << "no error writing " << path;
  return "";
}

Config model_config(int width) {
  Config c;
  for (const std::string& kv :
       {"model.width=" + std::to_string(width), std::string("model.heads=1"), std::string("model.ff_ratio=1"),
        std::string("model.coarse_layers=1"), std::string("model.fine_layers=1"), std::string("model.samples=8"),
        std::string("model.le_count=2"), std::string("model.le_layers=1")})
    c.set(kv);
  c.validate();
  return c;
}

}  // namespace

TEST(FullDisk, TextWriteFailsAndKeepsTheEarlierFile) {
  SmallDisk disk;
  const std::string path = disk / "report.json";
  write_file_atomic(path, "first version\n");
  expect_write_failure([&] { write_file_atomic(path, std::string(kTooBig, 'x')); }, path, disk);
  EXPECT_EQ(test::read_text(path), "first version\n");
  EXPECT_EQ(disk.leftover_temporaries(), 0);
}

TEST(FullDisk, PngWriteFailsAndKeepsTheEarlierFile) {
  SmallDisk disk;
  const std::string path = disk / "image.png";
  const auto small = torch::arange(4 * 4 * 3, torch::kLong).remainder(256).to(torch::kUInt8).reshape({4, 4, 3});
  write_png(path, small);
  // Noise does not compress: ~4 MiB of PNG.
  torch::manual_seed(1);
  const auto noise = torch::randint(0, 256, {1024, 1024, 4}, torch::kLong).to(torch::kUInt8);
  expect_write_failure([&] { write_png(path, noise); }, path, disk);
  EXPECT_TRUE(torch::equal(read_png(path), small));
  EXPECT_EQ(disk.leftover_temporaries(), 0);
}

TEST(FullDisk, CheckpointSaveFailsAndKeepsTheEarlierCheckpoint) {
  SmallDisk disk;
  const std::string path = disk / "checkpoint.pt";
  const Config small_cfg = model_config(16), big_cfg = model_config(96);
  torch::manual_seed(3);
  AbleNerf small(small_cfg.get<ModelConfig>()), big(big_cfg.get<ModelConfig>());
  torch::optim::Adam small_opt(small->parameters(), torch::optim::AdamOptions(1e-3));
  torch::optim::Adam big_opt(big->parameters(), torch::optim::AdamOptions(1e-3));
  TrainState st;
  st.step = 5;
  st.rng_state = torch::zeros({4}, torch::kUInt8);
  save_checkpoint(path, small_cfg, small, small_opt, st);
  st.step = 6;
  expect_write_failure([&] { save_checkpoint(path, big_cfg, big, big_opt, st); }, path, disk);
  AbleNerf again(small_cfg.get<ModelConfig>());
  torch::optim::Adam again_opt(again->parameters(), torch::optim::AdamOptions(1e-3));
  EXPECT_EQ(load_checkpoint(path, small_cfg, again, again_opt).step, 5);
  EXPECT_TRUE(torch::equal(again->parameters().front(), small->parameters().front()));
  EXPECT_EQ(disk.leftover_temporaries(), 0);
}

TEST(FullDisk, TrainingRunFailsWithOneLineAndALoadableCheckpoint) {
  // A whole `ablenerf train` on a disk that fills up after the first checkpoint (weights ~0.1 MiB
  // + checkpoint ~0.5 MiB fit once in 1 MiB, not twice plus a temporary).
  test::TempDir data_dir("ablenerf_disk_data");
  auto s = test::run_cli("synth --out " + data_dir.path() + " --res 16 --train-views 2 --test-views 1");
  ASSERT_EQ(s.exit_code, 0) << s.output;
  SmallDisk disk;
  if (!disk.is_tmpfs()) GTEST_SKIP() << "needs a tmpfs mount (root): a per-file limit cannot model a filling disk";
  std::string args =
      "train --data " + data_dir.path() + " --out " + (disk / "run") + " --set train.steps=20 --set train.ckpt_every=1";
  for (const auto& a : test::tiny_train_args()) args += " " + a;
  const auto r = test::run_cli(args);
  // An environment failure, not bad input: exit 1 and one line naming the file and the fix.
  EXPECT_EQ(r.exit_code, 1) << r.output;
  const auto pos = r.output.find("error: " + (disk / "run"));
  ASSERT_NE(pos, std::string::npos) << r.output;
  const std::string line = r.output.substr(pos, r.output.find('\n', pos) - pos);
  EXPECT_NE(line.find(": cannot write: "), std::string::npos) << r.output;
  EXPECT_NE(line.find("(disk full? free space in " + (disk / "run") + ")"), std::string::npos) << r.output;
  // The last checkpoint that fitted loads.
  const RunFolder run = RunFolder::open(disk / "run");
  AbleNerf model(run.config.get<ModelConfig>());
  torch::optim::Adam optim(model->parameters(), torch::optim::AdamOptions(1e-3));
  EXPECT_GE(load_checkpoint(run.checkpoint_path(), run.config, model, optim).step, 1);
}

TEST(MemoryLimit, TooLargeDatasetIsRefusedUpFrontWithTheSize) {
  test::TempDir t("ablenerf_mem");
  constexpr int kSide = 512, kFrames = 21;
  write_png(t / "big.png", torch::zeros({kSide, kSide, 4}, torch::kUInt8));
  test::write_file(t / "broken.png", "not a png");  // decoding it would fail with another message
  std::string frames;
  const std::string pose = "[[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]";
  for (int i = 0; i < kFrames; ++i)
    frames += std::string(i ? "," : "") + "{\"file_path\": \"" + (i + 1 < kFrames ? "big" : "broken") +
              "\", \"transform_matrix\": " + pose + "}";
  test::write_file(t / "transforms_train.json", "{\"camera_angle_x\": 0.69, \"frames\": [" + frames + "]}");
  LoadOptions o;
  o.memory_limit_bytes = int64_t(10) << 20;
  // 21 decoded float RGBA frames plus two full-size float RGBA scratch images:
  // (21 + 2) * 512 * 512 * 16 bytes = 92 MiB.
  const int64_t need_mib = (int64_t(kFrames) + 2) * kSide * kSide * 16 >> 20;
  ASSERT_EQ(need_mib, 92);
  try {
    Dataset::load(t.path(), o);
    FAIL() << "loaded a dataset larger than the memory limit";
  } catch (const InputError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find(std::to_string(need_mib) + " MiB"), std::string::npos) << msg;
    EXPECT_NE(msg.find("10 MiB"), std::string::npos) << msg;
    EXPECT_EQ(msg.find("broken"), std::string::npos) << "decoded before checking memory: " << msg;
  }
  // Control: with enough memory the same folder gets as far as the broken image.
  o.memory_limit_bytes = int64_t(1) << 30;
  try {
    Dataset::load(t.path(), o);
    FAIL() << "loaded a broken PNG";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("broken"), std::string::npos) << e.what();
  }
}
