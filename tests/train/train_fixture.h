#pragma once
// The training tests' fixture: a tiny dataset, a tiny config with a short schedule, quiet run options,
// config overrides, a run's log, a straight-versus-resumed run and a held-out score.
#include <gtest/gtest.h>

#include <fstream>
#include <functional>
#include <initializer_list>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "eval/evaluate.h"
#include "run/run_folder.h"
#include "synth/scene.h"
#include "test_util.h"
#include "train/trainer.h"
#include "util/config.h"
#include "model/grid_embedding.h"
#include "model/model_config.h"

namespace ablenerf::test {

// 1 where a grid table's entry can be read by a lookup, 0 in a dense level's unused rows (the
// entries a training step's gradient and Adam leave alone: GridEmbeddingImpl::table_entries_read),
// shaped like the table parameter.
inline torch::Tensor table_entries_mask(const GridEmbeddingImpl& grid) {
  const auto& table = grid.table_parameter();
  auto mask = torch::zeros({table.numel()}, table.options().requires_grad(false));
  for (const auto& r : grid.table_entries_read()) mask.slice(0, r.first, r.second).fill_(1);
  return mask.view(table.sizes());
}

// The lines of a run's log.jsonl, parsed, in order.
inline std::vector<nlohmann::json> read_log(const std::string& run) {
  std::vector<nlohmann::json> out;
  std::ifstream in(run + "/log.jsonl");
  for (std::string line; std::getline(in, line);) out.push_back(nlohmann::json::parse(line));
  return out;
}

// tiny_model_config() with the default IPE (16 degrees: the training tests' figures were measured
// with it) and a 12-step schedule of 32-ray steps (seconds on 2 cores).
inline Config tiny_config() {
  Config c = tiny_model_config();
  for (const char* kv : {"model.ipe_degrees=16", "train.steps=12", "train.rays_per_step=32", "train.micro_batch=16",
                         "train.lr_warmup_steps=2", "train.lr_decay_steps=0", "train.log_every=2", "train.eval_every=0",
                         "train.ckpt_every=5"})
    c.set(kv);
  c.validate();
  return c;
}

// `base` with `overrides` ("section.key=value", in order) set, then validated.
inline Config config_with(const Config& base, std::initializer_list<const char*> overrides) {
  Config c = base;
  for (const char* kv : overrides) c.set(kv);
  c.validate();
  return c;
}

// A small two-head model for gradient checks (width 16, 1 coarse and 2 fine layers, 8 samples, IPE 4,
// 3 LE): unequal layer counts and several heads, so that a mixed-up pass or head shows.
inline ModelConfig two_head_model() {
  ModelConfig m;
  m.width = 16;
  m.heads = 2;
  m.ff_ratio = 2;
  m.coarse_layers = 1;
  m.fine_layers = 2;
  m.samples = 8;
  m.ipe_degrees = 4;
  m.le_count = 3;
  m.le_layers = 1;
  return m;
}

// two_head_model() on a small hash grid front end: `levels` levels from `base` to `max` cells per
// side, 2^log2_table rows per level, the grid's cube of half-side `bound` (scene units).
inline ModelConfig two_head_grid_model(int levels, int log2_table, int base, int max, double bound) {
  ModelConfig m = two_head_model();
  m.embedding = Embedding::Grid;
  m.grid_levels = levels;
  m.grid_log2_table = log2_table;
  m.grid_base_resolution = base;
  m.grid_max_resolution = max;
  m.grid_bound = bound;
  return m;
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

// The options of a run without progress lines that reads `data` (the tiny scene by default) and
// writes the run folder `out`.
inline TrainOptions quiet_run(const std::string& out, const std::string& data = "") {
  TrainOptions o;
  o.data_dir = data.empty() ? tiny_dataset() : data;
  o.out_dir = out;
  o.quiet = true;
  return o;
}

// Trains `c` to the end in DIR/straight, and in DIR/pieces as two invocations: the first stops
// after `first_piece` steps, then `between` runs, then a resume (data folder from run.json)
// finishes the run. `options(out)` gives the options of a run folder. The caller compares the two.
inline void train_straight_and_in_pieces(const Config& c,
                                         const std::function<TrainOptions(const std::string&)>& options,
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
