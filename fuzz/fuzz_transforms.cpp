// libFuzzer target: the dataset json reader (data/transforms_json, torch-free) on arbitrary json
// text: a Blender transforms_train.json or a single transforms.json, chosen by the first byte,
// beside one valid 2x2 PNG (r_0.png) so that well-formed inputs reach pose parsing, path
// resolution, the PNG header and decoding of every frame. The same file is also read as a camera
// list (read_camera_json, what `render --cameras` uses).
// Bait for the path check: a valid PNG just outside the dataset folder (../outside.png) and a
// symlink inside it that points there (escape.png); both must be refused (seeds *_outside*.json).
// Every call must either succeed or throw InputError. Findings: any other exception, a crash, a
// sanitizer report, or a result that breaks the reader's promises (a resolved path outside the
// dataset folder, a non-finite pose, a focal length that is not positive and finite, an empty
// split). Seed ngp_zero_angle.json: camera_angle_x = 0 once gave an infinite focal length.
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>

#include "data/capture.h"
#include "data/transforms_json.h"
#include "fuzz_common.h"
#include "util/errors.h"
#include "util/image_codec.h"

namespace {

constexpr int kImageSide = 2;
constexpr int kChannels = 4;
constexpr uint8_t kGrey = 128;
// Decode at most this many frames per input, so that a json listing hundreds of frames measures
// the reader, not repeated decoding of the same 2x2 PNG.
constexpr size_t kMaxDecodedFrames = 16;

[[noreturn]] void finding(const char* what) {
  std::fprintf(stderr, "fuzz_transforms: %s\n", what);
  std::abort();
}

std::string dataset_dir() {
  static const std::string dir = [] {
    const std::string outside = ablenerf::fuzz::scratch_dir() + "/outside.png";
    const std::string d = ablenerf::fuzz::scratch_dir() + "/data";
    std::filesystem::create_directories(d);
    const std::vector<uint8_t> pixels(kImageSide * kImageSide * kChannels, kGrey);
    ablenerf::encode_png_file(d + "/r_0.png", kImageSide, kImageSide, kChannels, pixels.data());
    ablenerf::encode_png_file(outside, kImageSide, kImageSide, kChannels, pixels.data());
    std::filesystem::create_symlink(outside, d + "/escape.png");
    return std::filesystem::canonical(d).string();
  }();
  return dir;
}

bool inside(const std::string& path, const std::string& dir) {
  return path.size() > dir.size() && path.compare(0, dir.size(), dir) == 0 && path[dir.size()] == '/';
}

bool finite_pose(const ablenerf::Pose34& pose) {
  for (float v : pose)
    if (!std::isfinite(v)) return false;
  return true;
}

void check_dataset(const ablenerf::Capture& ds, const std::string& dir) {
  if (ds.width < 1 || ds.height < 1) finding("image size below 1");
  size_t decoded = 0;
  for (const auto& split : ds.splits) {
    if (split.frames.empty()) finding("a split without frames");
    for (const auto& fr : split.frames) {
      if (!inside(fr.image, dir)) finding("an image path resolved outside the dataset folder");
      if (!fr.depth.empty() && !inside(fr.depth, dir)) finding("a depth path resolved outside the dataset folder");
      if (!finite_pose(fr.pose)) finding("a non-finite pose");
      const auto& k = fr.camera;
      if (!(std::isfinite(k.fx) && std::isfinite(k.fy) && k.fx > 0 && k.fy > 0)) finding("bad focal length");
      if (k.width != ds.width || k.height != ds.height) finding("a frame's camera size differs from the capture's");
      if (decoded++ < kMaxDecodedFrames) {
        try {
          (void)ablenerf::decode_image_file(fr.image);  // what Dataset::load does next
        } catch (const ablenerf::InputError&) {
          // e.g. a frame that names the json file itself: refused like any bad PNG.
        }
      }
    }
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  const std::string dir = dataset_dir();
  // Low bit of the first byte: Blender layout or instant-ngp layout. Only one json exists at a time.
  const bool blender = (data[0] & 1) == 0;
  const std::string keep = dir + (blender ? "/transforms_train.json" : "/transforms.json");
  const std::string drop = dir + (blender ? "/transforms.json" : "/transforms_train.json");
  std::error_code ec;
  std::filesystem::remove(drop, ec);
  ablenerf::fuzz::write_bytes(keep, data + 1, size - 1);
  try {
    check_dataset(ablenerf::read_capture(dir, {}, 1), dir);
  } catch (const ablenerf::InputError&) {
    // Refused with a message naming the file and field: expected for bad input.
  }
  try {
    const ablenerf::CameraJson cams = ablenerf::read_camera_json(keep);
    if (cams.poses.empty()) finding("a camera list without poses");
    if (!(std::isfinite(cams.fx) && std::isfinite(cams.fy) && cams.fx > 0 && cams.fy > 0))
      finding("bad camera focal length");
    for (const auto& pose : cams.poses)
      if (!finite_pose(pose)) finding("a non-finite camera pose");
  } catch (const ablenerf::InputError&) {
  }
  return 0;
}
