// `ablenerf process`: photos or a video without poses -> a COLMAP capture (data/colmap_process.h),
// then one JSON line: what was registered and the command that trains on it.
#include <iostream>
#include <nlohmann/json.hpp>

#include "cli/command.h"
#include "cli/common.h"
#include "data/colmap_process.h"

namespace ablenerf::cli {
namespace cmd_process {

void setup(CLI::App& app) {
  auto o = std::make_shared<ProcessOptions>();
  app.add_option("--images", o->images, "Folder of JPEG/PNG photos of the scene (no poses needed)");
  app.add_option("--video", o->video, "A video of the scene instead of photos (frames taken by ffmpeg)");
  app.add_option("--frames", o->frames, "With --video: about this many evenly spaced frames")->capture_default_str();
  app.add_option("--out", o->out, "Capture folder to create (absent or empty)")->required();
  app.add_option("--camera-model", o->camera_model,
                 "COLMAP camera model: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, OPENCV_FISHEYE")
      ->capture_default_str();
  app.add_flag("!--per-image-camera", o->single_camera,
               "Intrinsics per photo (several cameras or zoom) instead of one shared camera");
  app.add_option("--matcher", o->matcher,
                 "exhaustive (every pair), sequential (neighbours by file name) or auto (sequential for a video, "
                 "exhaustive up to " +
                     std::to_string(kExhaustiveMaxImages) + " photos)")
      ->capture_default_str();
  app.add_option("--threads", o->threads, "COLMAP's threads (0 = all cores)")->capture_default_str();
  app.add_option("--colmap", o->colmap, "The COLMAP program")->capture_default_str();
  add_json_flag(app);
  app.callback([o] {
    const ProcessResult r = process_capture(*o, std::cerr);
    nlohmann::json j{{"capture", o->out},
                     {"images", r.images},
                     {"registered", r.registered},
                     {"points", r.points},
                     {"camera", r.camera},
                     {"matcher", r.matcher},
                     {"seconds", r.seconds},
                     {"next", "ablenerf train --data " + o->out + " --preset capture --out runs/NAME"}};
    std::cout << j.dump() << std::endl;
  });
}

}  // namespace cmd_process
ABLENERF_COMMAND("process", 15,
                 "Make a capture from your own photos or video: camera poses by COLMAP (structure from motion)",
                 cmd_process::setup);
}  // namespace ablenerf::cli
