#include "data/load_options.h"

namespace ablenerf {

LoadOptions load_options_for(const Config& c, std::vector<std::string> splits) {
  LoadOptions o;
  o.downscale = c.data.downscale;
  o.white_background = c.data.background == Background::White;
  o.near = c.data.near;
  o.far = c.data.far;
  o.scene = c.data.scene;
  o.bounds_from_config = c.data.bounds_from_config;
  o.masks = c.data.masks;
  o.splits = std::move(splits);
  return o;
}

}  // namespace ablenerf
