#pragma once
// A tiny dataset and model config shared by the training tests (seconds on 2 cores).
#include <gtest/gtest.h>

#include <functional>
#include <string>

#include "eval/evaluate.h"
#include "run/run_folder.h"
#include "synth/scene.h"
#include "test_util.h"
#include "train/trainer.h"
#include "util/config.h"

namespace ablenerf::test {

inline Config tiny_config() {
  Config c;
  for (const char* kv : {"model.width=16", "model.heads=1", "model.ff_ratio=1", "model.coarse_layers=1",
                         "model.fine_layers=1", "model.samples=8", "model.le_count=2", "model.le_layers=1",
                         "train.steps=12", "train.rays_per_step=32", "train.micro_batch=16",
                         "train.lr_warmup_steps=2", "train.lr_decay_steps=0", "train.log_every=2",
                         "train.eval_every=0", "train.ckpt_every=5", "eval.chunk=64"})
    c.set(kv);
  c.validate();
  return c;
}

// A 16x16 synthetic scene with 4 train and 2 test views, written once per process.
inline const std::string& tiny_dataset() {
  static TempDir dir("ablenerf_tiny_data");
  static bool written = false;
  if (!written) {
    SynthOptions o;
    o.res = 16;
    o.train_views = 4;
    o.test_views = 2;
    o.threads = 1;
    write_synthetic_dataset(dir.path(), o);
    written = true;
  }
  return dir.path();
}

// Trains `c` to the end in DIR/straight, and in DIR/pieces as two invocations: the first stops
// after `first_piece` steps, then `between` runs, then a resume (data folder from run.json)
// finishes the run. `options(out)` gives the options of a run folder. The caller compares the two.
inline void train_straight_and_in_pieces(const Config& c, const std::function<TrainOptions(const std::string&)>& options,
                                         const std::string& dir, int64_t first_piece,
                                         const std::function<void()>& between = {}) {
  ASSERT_EQ(train(c, options(dir + "/straight")), TrainResult::Finished);
  TrainOptions o = options(dir + "/pieces");
  o.max_steps_this_run = first_piece;
  ASSERT_EQ(train(c, o), TrainResult::StoppedEarly);
  if (between) between();
  o.max_steps_this_run = -1;
  o.resume = true;
  o.data_dir.clear();  // taken from run.json
  ASSERT_EQ(train(c, o), TrainResult::Finished);
}

// The mean PSNR of `run`'s test views (of eval_data's test views when given), without progress or notes.
inline double held_out_psnr(const std::string& run, const std::string& eval_data = "") {
  EvalOptions e;
  e.progress = false;
  e.data_dir = eval_data;
  e.note = [](const std::string&) {};
  return evaluate_run(RunFolder::open(run), e).at("mean").at("psnr").get<double>();
}

}  // namespace ablenerf::test
