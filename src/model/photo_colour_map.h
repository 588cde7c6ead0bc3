#pragma once
// The form of the per-photo colour map (train.photo_colour_map; model/photo_colour.h): "affine", a
// 3x4 affine map of the rendered sRGB colour; "gain", an exposure and white-balance gain per channel
// applied to the linear light before the sRGB curve. Torch-free, so the [train] section can name it.
#include "util/config_section.h"

namespace ablenerf {

enum class PhotoColourMap { Affine, Gain };

template <>
inline const EnumNames<PhotoColourMap> kEnumNames<PhotoColourMap>{{PhotoColourMap::Affine, "affine"},
                                                                  {PhotoColourMap::Gain, "gain"}};

}  // namespace ablenerf
