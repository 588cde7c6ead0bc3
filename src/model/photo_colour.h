#pragma once
// Per-photo colour (train.photo_colour; docs/MODEL.md, "Per-photo colour"), ablenerf's extension for
// phone captures: a camera changes exposure and white balance from photo to photo, which the paper's
// model (one colour per ray and view) can only bake into the scene. Each training photo p gets a map
// of its rays' rendered colours, applied to the coarse and fine colours before the loss, in one of
// two forms (train.photo_colour_map, model/photo_colour_map.h):
//  - "affine": rgb_p = (I + A_p) rgb + b_p on the sRGB colour (NeRF-W's and nerfacto's per-image
//    appearance in its smallest form, as Zip-NeRF's and gsplat's colour correction); 12 numbers;
//  - "gain": rgb_p = clamp(srgb(exp(l_p) * linear(rgb)), 0, 1), a gain per channel on the linear
//    light, where a camera's exposure and white balance act before its tone curve (the model sums its
//    colours in linear light too: docs/MODEL.md, section 7); 3 numbers, the log gains l_p. The clamp
//    is the sensor's saturation.
// The maps applied are the parameters minus their mean over the photos, so the average photo's map is
// the identity (for gains: their geometric mean is 1) and the scene keeps the photos' common look; a
// small decay (train.photo_colour_decay) bounds their spread. Novel views, eval and the viewer render
// the scene's own colour, the look of the average photo.
#include <torch/torch.h>

#include "model/photo_colour_map.h"

namespace ablenerf {

// The gains learn at this multiple of the run's learning rate (the parameter Adam sees is the log
// gains over it, as for the grid's table): a stop of exposure is a log gain of 0.69, far beyond what
// steps of the run's rate (about 1e-3) cover in a short run. At this scale a 1,500-step run recovers
// a jittered capture's gains to a quarter of their spread (docs/benchmarks/history.md, "Per-photo gains in
// linear light"; the run's own rate was not measured on that capture).
constexpr double kPhotoGainLrScale = 10.0;

class PhotoColourImpl : public torch::nn::Module {
 public:
  explicit PhotoColourImpl(int64_t photos, PhotoColourMap map = PhotoColourMap::Affine);
  // rgb (B,3) of rays drawn from photos `photo` (B,) (int64, < photos()) -> (B,3), through each
  // photo's map minus the maps' mean.
  torch::Tensor forward(const torch::Tensor& rgb, const torch::Tensor& photo);
  int64_t photos() const { return param_.size(0); }
  PhotoColourMap map() const { return map_; }
  // A rendered image (H,W,3) with training photo `photo`'s look: every pixel through its map,
  // clamped to [0,1], float32 (the viewer's look picker, `render --look`). photo in [0, photos()).
  torch::Tensor look(const torch::Tensor& image, int64_t photo);
  // The parameter before centring, all rows equal = every map the identity: "affine" (photos, 3, 4),
  // [A_p | b_p], weights name "photo_colour.delta"; "gain" (photos, 3), the log gains l_p over
  // kPhotoGainLrScale, "photo_colour.log_gain".
  const torch::Tensor& parameter() const { return param_; }
  // The parameter over the maps' values: 1 for "affine", kPhotoGainLrScale for "gain".
  double lr_scale() const { return map_ == PhotoColourMap::Gain ? kPhotoGainLrScale : 1.0; }

 private:
  PhotoColourMap map_;
  torch::Tensor param_;
};
TORCH_MODULE(PhotoColour);

// The weights' names of the two forms' parameters.
extern const char* const kPhotoColourAffineWeight;
extern const char* const kPhotoColourGainWeight;

}  // namespace ablenerf
