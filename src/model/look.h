#pragma once
// The look a novel view is rendered with (`render --look`, the viewer's picker): a training photo's
// per-photo colour map (model/photo_colour.h) and appearance code (model/appearance_code.h), whichever
// the run learnt; without a chosen photo, the photos' mean look (neither applied: both are centred).
#include <torch/torch.h>

#include <string>

#include "model/able_nerf.h"

namespace ablenerf {

struct PhotoLook {
  PhotoColourImpl* colour = nullptr;  // the photo's colour map, for PhotoColourImpl::look; null = none
  int64_t photo = -1;                 // the training photo, -1 for the mean look
  torch::Tensor appearance;           // (1, width) for ForwardOptions::appearance; undefined = none
};

// Training photos a look may name: those of the run's colour maps or codes, 0 when it learnt neither.
int64_t look_photos(AbleNerfImpl& model);

// Training photo `look`'s look, or the mean look (look < 0). InputError(where, field, ...) for a run
// that learnt neither colour maps nor codes, or a look out of range.
PhotoLook photo_look(AbleNerfImpl& model, int64_t look, const std::string& where, const std::string& field);

}  // namespace ablenerf
