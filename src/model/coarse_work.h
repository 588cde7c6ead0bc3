#pragma once
// What the coarse pass computes beside its attention and ray token: read by the forward
// (ForwardOptions::coarse, model/able_nerf.h) and by the FLOP count (model/flop_count.h), set from
// the training recipe by TrainConfig::coarse_work (train/train_config.h).

namespace ablenerf {

struct CoarseWork {
  // The coarse colour (rgb_coarse and its branch colours) at all. Rendering needs only the fine
  // colour: without it the coarse pass skips its LE branch and its last layer computes the ray
  // token's row alone; every fine output is unchanged. False when rendering, or at
  // train.coarse_weight = 0.
  bool colour = true;
  // The coarse colour with the coarse pass's LE transformer (the paper), or false: from its ray
  // token alone (the last layer computing the ray token's row alone); the fine pass is unchanged.
  bool le = true;
  // With le false: the coarse colour's view-dependent part from the coarse LE colour head applied
  // to the coarse ray token and the view code (no LE transformer), or none.
  bool view_head = false;
};

}  // namespace ablenerf
