// `ablenerf import`: converts a state dict of the authors' release (names in docs/weights.md,
// e.g. saved from a Lightning checkpoint with torch.save(ckpt["state_dict"], "w.pt")) into a
// run folder: RUN/config.toml (the resolved config) and RUN/weights.pt (save_weights format).
#include <torch/torch.h>

#include <iostream>
#include <nlohmann/json.hpp>

#include "cli/command.h"
#include "cli/common.h"
#include "model/able_nerf.h"
#include "util/fs.h"
#include "data/data_config.h"
#include "model/model_config.h"

namespace ablenerf::cli {
namespace cmd_import {

struct ImportArgs {
  std::string weights, out;
  ConfigOptions cfg;
};

void run_import(const ImportArgs& a) {
  Config c = resolve_config(a.cfg);
  // A size chosen from the capture when training (data.downscale = 0) has no capture here: the
  // images' own size, which eval --downscale changes.
  if (c.get<DataConfig>().downscale == 0) c.get<DataConfig>().downscale = 1;
  AbleNerf model(c.get<ModelConfig>());
  import_release_weights(model, read_weights_dict(a.weights), a.weights);
  ensure_dir(a.out);
  write_file_atomic(a.out + "/config.toml", c.to_toml());
  save_weights(model, a.out + "/weights.pt");
  nlohmann::json j;
  j["run"] = a.out;
  j["parameters"] = model->parameter_count();
  std::cout << j.dump() << std::endl;
}

void setup(CLI::App& app) {
  auto a = std::make_shared<ImportArgs>();
  app.add_option("--weights", a->weights, "Release state dict (.pt, name -> tensor)")->required();
  a->cfg.add_to(app, true);
  app.add_option("--out", a->out, "Run folder to create")->required();
  add_json_flag(app);
  app.callback([a] { run_import(*a); });
}

}  // namespace cmd_import
ABLENERF_COMMAND("import", 65, "Import weights of the authors' release into a run", cmd_import::setup);
}  // namespace ablenerf::cli
