#include "data/load_options.h"
#include "data/data_config.h"

namespace ablenerf {

LoadOptions load_options_for(const Config& c, std::vector<std::string> splits) {
  LoadOptions o;
  o.downscale = c.get<DataConfig>().downscale;
  o.white_background = c.get<DataConfig>().background == Background::White;
  o.near = c.get<DataConfig>().near;
  o.far = c.get<DataConfig>().far;
  o.scene = c.get<DataConfig>().scene;
  o.bounds_from_config = c.get<DataConfig>().bounds_from_config;
  o.ndc = c.get<DataConfig>().ndc;
  o.frame.centre = c.get<DataConfig>().scene_centre;
  o.frame.radius = c.get<DataConfig>().scene_radius;
  o.masks = c.get<DataConfig>().masks;
  o.splits = std::move(splits);
  return o;
}

}  // namespace ablenerf
