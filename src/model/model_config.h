#pragma once
// The [model] section of the run configuration (util/config_section.h), registered below: what the model computes
// (docs/MODEL.md), owned by the model module.
#include "util/config_section.h"

namespace ablenerf {

enum class ViewEncoding { Release, Paper };  // model.view_encoding (model/view_encoding.h)
enum class Embedding { Ipe, Grid };  // model.embedding: the paper's IPE or the grid front end (model/grid_embedding.h)

template <>
inline const EnumNames<ViewEncoding> kEnumNames<ViewEncoding>{{ViewEncoding::Release, "release"},
                                                              {ViewEncoding::Paper, "paper"}};
template <>
inline const EnumNames<Embedding> kEnumNames<Embedding>{{Embedding::Ipe, "ipe"}, {Embedding::Grid, "grid"}};

struct ModelConfig {
  static constexpr const char* kName = "model";
  static constexpr int kOrder = 0;

  int width = 192;        // token width d
  int heads = 3;          // attention heads (head dim = width / heads)
  int ff_ratio = 3;       // feed-forward width = width * ff_ratio
  int coarse_layers = 2;  // AB transformer blocks, coarse pass
  int fine_layers = 6;    // AB transformer blocks, fine pass
  int samples = 96;       // intervals per ray (coarse and fine)
  // What turns a frustum Gaussian into the features of its token: "ipe", the paper's integrated
  // positional encoding (stage 2), or "grid", a multiresolution hash grid (model/grid_embedding.h).
  Embedding embedding = Embedding::Ipe;
  int ipe_degrees = 16;  // IPE frequencies 2^0 .. 2^(ipe_degrees-1)
  // The grid front end (model.embedding = "grid"): levels of 2^grid_log2_table rows of
  // grid_features floats, from grid_base_resolution to grid_max_resolution cells per side.
  int grid_levels = 16;
  int grid_features = 2;
  int grid_log2_table = 19;
  int grid_base_resolution = 16;
  int grid_max_resolution = 2048;
  // IPE frequencies 2^0 .. 2^(grid_ipe_degrees-1) put beside the grid's features in the token (0 =
  // the grid alone): the grid carries no position of its own, and without it the transformer
  // memorised the training rays of a real capture (docs/benchmarks/history.md, "Grid front end").
  int grid_ipe_degrees = 4;
  double grid_lr_scale = 20;  // the table's learning rate over the run's (instant-ngp's 1e-2 at lr 5e-4)
  double grid_bound = 1.5;    // bounded scenes: the grid spans [-grid_bound, grid_bound]^3 of the world
  // The proposal field (model/proposal.h; docs/MODEL.md, "Proposal sampling"): a small density grid
  // read at proposal_samples intervals of every ray places the coarse pass's samples where the
  // surfaces are, in place of the paper's even spacing. 0 = off (the paper). Its hash grid:
  // proposal_levels levels from grid_base_resolution to proposal_max_resolution cells per side, of
  // 2^proposal_log2_table rows (learning rate scaled by grid_lr_scale as the front end's).
  int proposal_samples = 0;
  int proposal_levels = 5;
  int proposal_max_resolution = 128;
  int proposal_log2_table = 16;
  int le_count = 32;        // learnable embeddings; 0 = the paper's "no LE" ablation
  int le_layers = 2;        // LE self-attention blocks
  bool mask = true;         // causal volume mask (docs/MODEL.md, section 4) (false = bidirectional ablation)
  bool randomized = false;  // stratified jitter of coarse samples and resampling (released: off)
  ViewEncoding view_encoding = ViewEncoding::Release;  // "release": d, 4 linear freqs 1..8; "paper": 16 octave bands
  double resample_padding = 0.01;                      // added to every blurred weight before inverse-CDF sampling

  template <class F>
  void visit(F&& f) {
    f("width", &width);
    f("heads", &heads);
    f("ff_ratio", &ff_ratio);
    f("coarse_layers", &coarse_layers);
    f("fine_layers", &fine_layers);
    f("samples", &samples);
    f("embedding", &embedding);
    f("ipe_degrees", &ipe_degrees);
    f("grid_levels", &grid_levels);
    f("grid_features", &grid_features);
    f("grid_log2_table", &grid_log2_table);
    f("grid_base_resolution", &grid_base_resolution);
    f("grid_max_resolution", &grid_max_resolution);
    f("grid_ipe_degrees", &grid_ipe_degrees);
    f("grid_lr_scale", &grid_lr_scale);
    f("grid_bound", &grid_bound);
    f("proposal_samples", &proposal_samples);
    f("proposal_levels", &proposal_levels);
    f("proposal_max_resolution", &proposal_max_resolution);
    f("proposal_log2_table", &proposal_log2_table);
    f("le_count", &le_count);
    f("le_layers", &le_layers);
    f("mask", &mask);
    f("randomized", &randomized);
    f("view_encoding", &view_encoding);
    f("resample_padding", &resample_padding);
  }

  void validate(const SectionCheck& need) const {
    need(width > 0, "width", "must be positive");
    need(heads > 0 && width % heads == 0, "heads", "must divide model.width");
    need(ff_ratio > 0, "ff_ratio", "must be positive");
    need(coarse_layers >= 1, "coarse_layers", "must be at least 1 (the resampler reads its last layer)");
    need(fine_layers >= 1, "fine_layers", "must be at least 1");
    need(samples >= 2, "samples", "must be at least 2");
    need(ipe_degrees >= 1 && ipe_degrees <= 30, "ipe_degrees", "must be in 1..30");
    // The hash grid's limits (kernels/hash_grid_shape.h).
    need(grid_levels >= 1 && grid_levels <= 32, "grid_levels", "must be in 1..32");
    need(grid_features >= 1 && grid_features <= 8, "grid_features", "must be in 1..8");
    need(grid_log2_table >= 1 && grid_log2_table <= 24, "grid_log2_table", "must be in 1..24");
    need(grid_base_resolution >= 1, "grid_base_resolution", "must be at least 1");
    need(grid_max_resolution >= grid_base_resolution && grid_max_resolution <= (1 << 20), "grid_max_resolution",
         "must be in model.grid_base_resolution..1048576");
    need(grid_ipe_degrees >= 0 && grid_ipe_degrees <= 30, "grid_ipe_degrees", "must be in 0..30");
    need(grid_lr_scale > 0, "grid_lr_scale", "must be positive");
    need(grid_bound > 0, "grid_bound", "must be positive");
    need(proposal_samples == 0 || (proposal_samples >= 2 && proposal_samples <= 1024), "proposal_samples",
         "must be 0 (off) or in 2..1024");
    need(proposal_levels >= 1 && proposal_levels <= 32, "proposal_levels", "must be in 1..32");
    need(proposal_log2_table >= 1 && proposal_log2_table <= 24, "proposal_log2_table", "must be in 1..24");
    need(proposal_max_resolution >= grid_base_resolution && proposal_max_resolution <= (1 << 20),
         "proposal_max_resolution", "must be in model.grid_base_resolution..1048576");
    need(le_count >= 0, "le_count", "must be >= 0");
    need(le_layers >= 0, "le_layers", "must be >= 0");
    need(resample_padding >= 0, "resample_padding", "must be >= 0");
  }
};
ABLENERF_CONFIG_SECTION(ModelConfig);

}  // namespace ablenerf
