#pragma once
// `ablenerf process`: a capture from photos (or a video) that have no poses yet, through COLMAP's
// structure from motion (Debian's `colmap`, CPU), as nerfstudio's ns-process-data and
// instant-ngp's colmap2nerf.py do. It writes a COLMAP capture that the loaders read directly:
//   OUT/images/          the photos (copied, names kept) or the video's frames (frame_00001.jpg ...)
//   OUT/database.db      COLMAP's features and matches
//   OUT/sparse/0/        {cameras,images,points3D}.bin: of the models the mapper made, the one that
//                        registered the most images
//   OUT/colmap.log       everything COLMAP and ffmpeg printed
// Photos COLMAP could not register stay in images/ and are left out by the loader.
#include <iosfwd>
#include <string>
#include <vector>

namespace ablenerf {

struct ProcessOptions {
  std::string images;  // a folder of JPEG / PNG photos (not searched recursively), or
  std::string video;   // a video file, sampled to about `frames` evenly spaced frames
  int frames = 150;
  std::string out;  // the capture folder to create: absent or empty
  // COLMAP's camera model: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, OPENCV_FISHEYE.
  std::string camera_model = "OPENCV";
  bool single_camera = true;  // one camera (intrinsics shared by every photo), as one phone or lens
  // exhaustive (every pair), sequential (neighbours in file-name order: video), or auto: sequential
  // for a video, exhaustive for up to kExhaustiveMaxImages photos, sequential above.
  std::string matcher = "auto";
  int threads = 0;                  // COLMAP's threads; 0 = all cores
  std::string colmap = "colmap";    // the COLMAP program
  std::string ffmpeg = "ffmpeg";    // for --video
  std::string ffprobe = "ffprobe";  // counts the video's frames
};

constexpr int kExhaustiveMaxImages = 300;
// Fewer registered images than this is no capture.
constexpr int kMinRegisteredImages = 3;

struct ProcessResult {
  int images = 0;      // photos or frames given to COLMAP
  int registered = 0;  // with a pose in sparse/0
  size_t points = 0;
  std::string camera;  // e.g. "OPENCV 1920x1080"
  std::string matcher;
  double seconds = 0;
};

// Checks the options (InputError naming the flag), then runs the whole pipeline, printing one line
// per stage to `progress`. COLMAP failing or registering too few images is an InputError naming
// OUT/colmap.log (the photos do not overlap enough); COLMAP or ffmpeg missing is an
// EnvironmentError saying what to install.
ProcessResult process_capture(const ProcessOptions& options, std::ostream& progress);

// The COLMAP command lines of the pipeline for `n_images` photos, in order: feature extraction,
// matching, mapping (exposed for the tests).
std::vector<std::vector<std::string>> colmap_commands(const ProcessOptions& options, const std::string& out,
                                                      int n_images);

}  // namespace ablenerf
