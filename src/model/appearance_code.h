#pragma once
// Per-photo appearance codes (train.appearance_code; docs/MODEL.md, "Per-photo appearance code"),
// ablenerf's extension for captures whose light changes from photo to photo beyond what a colour map
// of the photo (model/photo_colour.h) can say: NeRF-W's appearance embedding (Martin-Brualla et al.
// 2021, section 4.1) and nerfacto's, entered where the paper's model is view-dependent. Each
// training photo p has a code a_p of the model's width, added to the view token (the query that
// decodes the learnable embeddings into the LE colour, docs/MODEL.md section 6) of that photo's
// rays; the ray token's colour and every attention over the samples are untouched, so the geometry
// cannot take up a photo's look.
//
// The codes added are the parameters minus their mean over the photos, so the average photo's code
// is zero and a model rendered without a code (novel views, eval's plain protocol) has the photos'
// mean look; a small decay (train.appearance_code_decay) bounds their spread.
#include <torch/torch.h>

namespace ablenerf {

class AppearanceCodeImpl : public torch::nn::Module {
 public:
  // Codes of `width` numbers for `photos` training photos, all zero (every photo the mean look).
  AppearanceCodeImpl(int64_t photos, int64_t width);
  // The centred codes of photos `photo` (B,) (int64, < photos()): (B, width).
  torch::Tensor forward(const torch::Tensor& photo);
  // Training photo `photo`'s centred code alone, (1, width), without gradient: the look a novel
  // view is rendered with (`render --look`, the viewer's picker).
  torch::Tensor look(int64_t photo);
  int64_t photos() const { return codes_.size(0); }
  const torch::Tensor& parameter() const { return codes_; }

 private:
  torch::Tensor codes_;  // (photos, width), weights name kAppearanceCodeWeight
};
TORCH_MODULE(AppearanceCode);

// The weights' name of the codes.
extern const char* const kAppearanceCodeWeight;

}  // namespace ablenerf
