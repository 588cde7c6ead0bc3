#pragma once
// Per-photo colour (train.photo_colour; docs/MODEL.md, "Per-photo colour"), ablenerf's extension for
// phone captures: a camera changes exposure and white balance from photo to photo, which the paper's
// model (one colour per ray and view) can only bake into the scene. Each training photo p gets a 3x4
// affine map of the rendered sRGB colour, rgb_p = (I + A_p) rgb + b_p (NeRF-W's and nerfacto's
// per-image appearance in its smallest form, as Zip-NeRF's and gsplat's colour correction), applied
// to the coarse and fine colours of the photo's rays before the loss. The maps applied are the
// parameters minus their mean over the photos, so the average photo's map is the identity and the
// scene keeps the photos' common look; a small decay (train.photo_colour_decay) bounds their spread.
// Novel views, eval and the viewer render the scene's own colour, the look of the average photo.
#include <torch/torch.h>

#include <string>

namespace ablenerf {

class PhotoColourImpl : public torch::nn::Module {
 public:
  explicit PhotoColourImpl(int64_t photos);
  // rgb (B,3) of rays drawn from photos `photo` (B,) (int64, < photos()) -> (B,3), through each
  // photo's map minus the maps' mean.
  torch::Tensor forward(const torch::Tensor& rgb, const torch::Tensor& photo);
  int64_t photos() const { return delta_.size(0); }
  // A rendered image (H,W,3) with training photo `photo`'s look: every pixel through its map,
  // clamped to [0,1], float32 (the viewer's look picker, `render --look`). photo in [0, photos()).
  torch::Tensor look(const torch::Tensor& image, int64_t photo);
  // The parameter: (photos, 3, 4), [A_p | b_p] before centring; all equal = every map the identity.
  const torch::Tensor& delta() const { return delta_; }

 private:
  torch::Tensor delta_;
};
TORCH_MODULE(PhotoColour);

// The map that gives training photo `look`'s look, or nullptr for the photos' mean look (look < 0).
// `colour` is the model's per-photo colour (AbleNerf::photo_colour(), null when the run learnt
// none). InputError(where, field, ...) for a run without per-photo colour or a look out of range.
PhotoColourImpl* photo_look(PhotoColourImpl* colour, int64_t look, const std::string& where, const std::string& field);

}  // namespace ablenerf
