// `ablenerf synth`: renders an embedded scene with exact test-view depth: the demo scene (diffuse,
// mirror and glass spheres under a procedural sky) as a Blender-format dataset, or as a
// nerfstudio-layout capture through a distorted lens and/or with the environment as background;
// or a furnished room photographed from inside (`--scene room`), a nerfstudio-layout capture.
#include <chrono>
#include <cstdio>
#include <iostream>
#include <memory>

#include "cli/command.h"
#include "cli/common.h"
#include "synth/scene.h"
#include "util/log.h"
#include "util/errors.h"

namespace ablenerf::cli {
namespace cmd_synth {

struct SynthArgs {
  std::string out;
  bool json = false;
  synth::SynthOptions opts;
};

// One self-overwriting stderr line: views done / total and a linear ETA.
void print_progress(int done, int total, std::chrono::steady_clock::time_point start) {
  const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const double eta = done > 0 ? elapsed * (total - done) / done : 0.0;
  std::fprintf(stderr, "\rsynth: %d/%d views, ETA %.1f s   ", done, total, eta);
  if (done == total) std::fputc('\n', stderr);
  std::fflush(stderr);
}

void setup(CLI::App& app) {
  auto a = std::make_shared<SynthArgs>();
  app.add_option("--out", a->out, "Output dataset folder (created if missing)")->required();
  app.add_option("--scene", a->opts.scene,
                 "demo: three spheres under a sky (default); room: a furnished room photographed from inside, "
                 "cameras looking outward")
      ->capture_default_str();
  app.add_option("--res", a->opts.res, "Image width and height in pixels (>= 8)")->capture_default_str();
  app.add_option("--train-views", a->opts.train_views, "Number of training views (>= 1)")->capture_default_str();
  app.add_option("--test-views", a->opts.test_views, "Number of test views (>= 1)")->capture_default_str();
  app.add_option("--seed", a->opts.seed, "Seed of the camera positions (demo: the training views'; room: every view's)")
      ->capture_default_str();
  app.add_option("--threads", a->opts.threads, "Worker threads (0 = all cores)")->capture_default_str();
  app.add_option("--lens", a->opts.lens,
                 "pinhole, or opencv: render through a wide-angle lens with barrel distortion (OpenCV model)")
      ->capture_default_str();
  app.add_option("--background", a->opts.background,
                 "transparent, or environment: the sky and ground at infinity behind the objects (demo only)")
      ->capture_default_str();
  app.add_option("--layout", a->opts.layout,
                 "auto (blender; nerfstudio for the room and the lens or background variants), blender or nerfstudio")
      ->capture_default_str();
  app.add_option("--exposure-jitter", a->opts.exposure_jitter,
                 "Train views only: each photo's exposure off by up to this many stops (centred; truth in scene.json)")
      ->capture_default_str();
  app.add_option("--white-balance-jitter", a->opts.white_balance_jitter,
                 "Train views only: red and blue gains off by up to this many stops (centred)")
      ->capture_default_str();
  app.add_option("--pose-noise-deg", a->opts.pose_noise_deg,
                 "Train views only: the written pose turned by exactly this many degrees about a random axis")
      ->capture_default_str();
  app.add_option("--pose-noise-shift", a->opts.pose_noise_shift,
                 "Train views only: the written camera centre moved by this fraction of its distance (demo: to the "
                 "origin; room: to what it looks at)")
      ->capture_default_str();
  app.add_flag(
      "--distractor", a->opts.distractor,
      "Train views only: a magenta ball at a new place in every photo, with masks (mask_path) that leave it out "
      "(demo only)");
  add_json_flag(app, a->json);
  app.callback([a] {
    synth::validate(a->opts);  // fail before creating any folder
    const auto start = std::chrono::steady_clock::now();
    synth::SynthOptions opts = a->opts;
    if (log_enabled(LogLevel::Info))  // --quiet: no progress line
      opts.progress = [start](int done, int total) { print_progress(done, total, start); };
    write_synthetic_dataset(a->out, opts);
    const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    if (a->json) {
      std::cout << nlohmann::json{{"out", a->out},
                                  {"scene", opts.scene},
                                  {"train_views", opts.train_views},
                                  {"test_views", opts.test_views},
                                  {"width", opts.res},
                                  {"height", opts.res},
                                  {"seconds", secs}}
                       .dump()
                << std::endl;
      return;
    }
    std::fprintf(stdout, "synth: wrote %d train + %d test views (%dx%d, test depth maps) to %s in %.1f s\n",
                 opts.train_views, opts.test_views, opts.res, opts.res, a->out.c_str(), secs);
  });
}

}  // namespace cmd_synth
ABLENERF_COMMAND("synth", 10,
                 "Render the embedded demo scene (diffuse, mirror and glass objects) as a Blender dataset (or a "
                 "nerfstudio capture: --lens, --background), or a furnished room from inside (--scene room)",
                 cmd_synth::setup);
}  // namespace ablenerf::cli
