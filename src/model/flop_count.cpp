#include "model/flop_count.h"

#include <cstdint>

#include "data/rays.h"
#include "model/ipe.h"
#include "model/proposal.h"
#include "model/view_encoding.h"
#include "model/model_config.h"

namespace ablenerf {

namespace {

// The backward of a product whose two operands both need gradients is two products of the same
// size (one per operand); a product with one constant operand (input features, no-grad probes)
// needs only the other operand's gradient.
constexpr double kBackwardBothOperands = 2.0;
constexpr double kBackwardOneOperand = 1.0;
constexpr int64_t kRgb = kRgbChannels;
constexpr int64_t kQkv = 3, kKv = 2;
constexpr int64_t kVolumeEmbeddingHiddenLayers = 3;  // 4 Linear layers: in->E, then 3 x E->E

// Accumulates products with their backward multiplier.
struct Tally {
  FlopCount c;
  // m x k times k x n.
  void product(double m, double k, double n, double backward_factor) {
    const double f = kFlopPerMac * m * k * n;
    c.forward += f;
    c.backward += backward_factor * f;
  }
};

// One post-norm transformer block per ray: lq queries attending to lk keys. `q_per_ray` is
// false when the queries are shared by the whole batch (the LE cross-attention), so their
// projection is a per-call cost, not a per-ray one.
void transformer_block(Tally& t, double lq, double lk, double e, double ff, bool self, bool q_per_ray) {
  if (self) {
    t.product(lq, e, kQkv * e, kBackwardBothOperands);  // packed Q/K/V
  } else {
    if (q_per_ray) t.product(lq, e, e, kBackwardBothOperands);
    t.product(lk, e, kKv * e, kBackwardBothOperands);  // packed K/V
  }
  // Scores and weighted values, summed over heads (heads x dh = E).
  t.product(lq, e, lk, kBackwardBothOperands);
  t.product(lq, lk, e, kBackwardBothOperands);
  t.product(lq, e, e, kBackwardBothOperands);   // output projection
  t.product(lq, e, ff, kBackwardBothOperands);  // feed-forward in
  t.product(lq, ff, e, kBackwardBothOperands);  // feed-forward out
}

// The width of the grid's features (levels x features per level), 0 with the paper's IPE.
double grid_width(const ModelConfig& c) {
  return c.embedding == Embedding::Grid ? double(c.grid_levels) * c.grid_features : 0.0;
}

// The volume-embedding MLP of one pass. Its input is the IPE features (no gradient) or, with the
// grid front end, the grid's features (whose gradient flows into the table: one more product of
// their width) beside grid_ipe_degrees IPE bands.
void volume_embedding(Tally& t, const ModelConfig& c) {
  const double e = c.width, s = c.samples, grid = grid_width(c);
  const double in = grid > 0 ? grid + static_cast<double>(ipe_width(c.grid_ipe_degrees))
                             : static_cast<double>(ipe_width(c.ipe_degrees));
  t.product(s, in, e, kBackwardOneOperand);
  t.c.backward += kFlopPerMac * s * e * grid;
  for (int64_t i = 0; i < kVolumeEmbeddingHiddenLayers; ++i) t.product(s, e, e, kBackwardBothOperands);
}

// The proposal field (docs/MODEL.md, "Proposal sampling"): proposal_samples grid reads through a
// hidden layer of kProposalHidden to one density; the table gets gradients, so both operands of
// each product do.
void proposal(Tally& t, const ModelConfig& c) {
  if (c.proposal_samples <= 0) return;
  const double p = c.proposal_samples, w = double(c.proposal_levels) * c.grid_features;
  t.product(p, w, kProposalHidden, kBackwardBothOperands);
  t.product(p, kProposalHidden, 1, kBackwardBothOperands);
}

// The LE colour head: a hidden layer over the decoded LE (or the ray token) beside the view code.
void le_head(Tally& t, const ModelConfig& c) {
  const double e = c.width, view = static_cast<double>(view_encoding_width(c.view_encoding));
  t.product(1, e + view, e, kBackwardBothOperands);  // hidden layer
  t.product(1, e, kRgb, kBackwardBothOperands);      // output
}

void le_branch(Tally& t, const ModelConfig& c) {
  const double e = c.width, ff = double(c.width) * c.ff_ratio, s = c.samples, n = c.le_count;
  transformer_block(t, n, s, e, ff, /*self=*/false, /*q_per_ray=*/false);  // LE x volumes
  for (int64_t j = 0; j < c.le_layers; ++j) transformer_block(t, n, n, e, ff, true, true);
  transformer_block(t, 1, n, e, ff, /*self=*/false, /*q_per_ray=*/true);  // view decodes LE
  le_head(t, c);
}

// One pass: its volume MLP, its AB transformer, the resampling probe and what it colours with.
void pass(Tally& t, const ModelConfig& c, int layers, bool colour, bool le_transformer, bool head_on_ray_token) {
  const double e = c.width, ff = double(c.width) * c.ff_ratio, tokens = double(c.samples) + 1;
  volume_embedding(t, c);
  // AB transformer over the ray token plus S volume tokens (the full score matrix is computed: the
  // causal mask is added, not skipped). Without an LE transformer to feed, the last layer computes
  // the ray token's row alone: one query against every key.
  const bool last_row_only = !colour || !le_transformer;
  for (int i = 0; i < layers; ++i) {
    if (last_row_only && i + 1 == layers)
      transformer_block(t, 1, tokens, e, ff, /*self=*/false, /*q_per_ray=*/true);
    else
      transformer_block(t, tokens, tokens, e, ff, true, true);
  }
  // Resampling probe: the ray token's query against every key, without gradient.
  t.product(1, e, tokens, 0.0);
  if (!colour) return;
  t.product(1, e, kRgb, kBackwardBothOperands);  // ray colour head
  if (le_transformer)
    le_branch(t, c);
  else if (head_on_ray_token)
    le_head(t, c);
}

}  // namespace

FlopCount model_flops_per_ray(const ModelConfig& c, const CoarseWork& coarse) {
  Tally t;
  const bool le = c.le_count > 0;
  if (le) {
    // View token, shared by both passes; its input (the view encoding) needs no gradient.
    t.product(1, static_cast<double>(view_encoding_width(c.view_encoding)), c.width, kBackwardOneOperand);
  }
  pass(t, c, c.coarse_layers, coarse.colour, le && coarse.le, le && coarse.view_head);
  pass(t, c, c.fine_layers, /*colour=*/true, le, /*head_on_ray_token=*/false);
  proposal(t, c);
  return t.c;
}

}  // namespace ablenerf
