#pragma once
// Helpers shared by the test suites: scratch folders, the shared data folder, running the CLI.
#include <torch/torch.h>

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "data/rays.h"
#include "kernels/cpu_parallel.h"
#include "util/config.h"
#include "model/model_config.h"

namespace ablenerf::test {

// A pinhole camera (no lens distortion) of the given size, focal lengths and principal point.
inline Intrinsics pinhole(int width, int height, double fx, double fy, double cx, double cy) {
  Intrinsics k;
  k.width = width;
  k.height = height;
  k.fx = fx;
  k.fy = fy;
  k.cx = cx;
  k.cy = cy;
  return k;
}

// A tiny model with a small proposal field (model/proposal.h): 24 proposal intervals, a 3-level
// grid of 4-32 cells and 2^10 rows; the paper's IPE for the tokens.
// A small model with learnable embeddings (width 16, 2 heads, 4 samples, 2 LEs): enough to carry
// per-photo parameters through weights files and the view token.
inline ModelConfig small_le_model_config() {
  ModelConfig cfg;
  cfg.width = 16;
  cfg.heads = 2;
  cfg.samples = 4;
  cfg.le_count = 2;
  return cfg;
}

inline ModelConfig proposal_model_config() {
  ModelConfig m;
  m.width = 16;
  m.heads = 2;
  m.ff_ratio = 2;
  m.coarse_layers = 1;
  m.fine_layers = 1;
  m.samples = 8;
  m.le_count = 2;
  m.le_layers = 1;
  m.grid_base_resolution = 4;
  m.grid_lr_scale = 10;
  m.grid_bound = 1.5;
  m.proposal_samples = 24;
  m.proposal_levels = 3;
  m.proposal_max_resolution = 32;
  m.proposal_log2_table = 10;
  return m;
}

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

// The smallest model the tests use (width 16, one head, one layer per transformer, 8 samples, 2 LE,
// IPE of 4 degrees), rendering in chunks of 64 rays: what eval and view tests render, and what the
// training tests' tiny_config (tests/train/train_fixture.h) adds a short schedule to.
// Inline: the kernel tests link no Config and never call it.
inline Config tiny_model_config() {
  Config c;
  for (const char* kv :
       {"model.width=16", "model.heads=1", "model.ff_ratio=1", "model.coarse_layers=1", "model.fine_layers=1",
        "model.samples=8", "model.ipe_degrees=4", "model.le_count=2", "model.le_layers=1", "eval.chunk=64"})
    c.set(kv);
  c.validate();
  return c;
}

// A preset of configs/ (capture, blender, ...) as `--preset NAME` reads it, validated.
// Inline, like tiny_model_config: the kernel tests link no Config.
inline Config preset_config(const std::string& name) {
  Config c = Config::load(source_dir() + "/configs/" + name + ".toml");
  c.validate();
  return c;
}

// ../shared/data/nerf_synthetic/lego beside the repository, or "" when it is absent (optional test data: tests that
// need it skip).
std::string lego_dir();

// ../shared/weights beside the repository, or "" when absent (optional: tests that need it skip).
std::string shared_weights_dir();

struct CommandResult {
  int exit_code = -1;
  std::string output;  // stdout and stderr together
};

// An environment variable set for the scope (what run_cli starts inherits it), its previous value
// (or its absence) restored after.
class ScopedEnv {
 public:
  ScopedEnv(const char* name, const std::string& value);
  ~ScopedEnv();
  ScopedEnv(const ScopedEnv&) = delete;
  ScopedEnv& operator=(const ScopedEnv&) = delete;

 private:
  const char* name_;
  std::optional<std::string> previous_;
};

// Runs the built CLI ($ABLENERF_BIN) with the given argument string through /bin/sh.
CommandResult run_cli(const std::string& args);

// Writes a text file (creating parent folders).
void write_file(const std::string& path, const std::string& text);

// A .npy file: magic, version `major`.0, the header length, `dict` padded with spaces and a '\n'
// to a multiple of 64 bytes (as numpy pads it), then `data`.
std::string npy_file(const std::string& dict, const std::string& data, int major = 1);
// LLFF's poses_bounds.npy: float64 (n, 17), `rows` holding the n rows one after another.
std::string llff_poses_bounds_npy(const std::vector<double>& rows);

// The pixel footprint of the Blender scenes: mip-NeRF's base radius (2/sqrt(12) / fx) of an
// 800x800 image with camera_angle_x 0.6911, the radius of the paper's rays (data/rays.h).
constexpr double kBlenderPixelRadius = 5.196e-4;

// `n` rays looking from around (0, 0, 4) towards the origin: origins (0, 0, 4) and directions
// (0, 0, -1), each jittered by N(0, 0.2^2) per coordinate from a generator seeded with `seed` (the
// global RNG is left alone); radius kBlenderPixelRadius. Same seed and n, same rays.
Rays random_rays(int64_t n, uint64_t seed, torch::Dtype dtype = torch::kFloat);

// LibTorch's intra-op thread count set to `threads` for the scope, restored afterwards. The CPU
// ray split and the optimiser's loops take the larger of this count and OpenBLAS's
// (kernels/cpu_parallel.h), so 2 makes them split on any machine, and 1 holds OpenBLAS's pool to
// one thread as well, so that the scope runs serially.
class IntraOpThreads {
 public:
  explicit IntraOpThreads(int threads);
  ~IntraOpThreads();
  IntraOpThreads(const IntraOpThreads&) = delete;
  IntraOpThreads& operator=(const IntraOpThreads&) = delete;

 private:
  int previous_;
  std::optional<SingleThreadedBlas> single_blas_;
};

// Runs `f` and expects an InputError naming `file`, a field that equals `field` (exact_field) or
// contains it, and a message that contains `what` and is one line. Any other outcome is a failure.
void expect_input_error(const std::function<void()>& f, const std::string& file, const std::string& field,
                        const std::string& what, bool exact_field);

}  // namespace ablenerf::test
