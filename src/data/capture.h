#pragma once
// A capture's metadata, whatever its format, and the registry of formats that read it (docs/
// ARCHITECTURE.md, "Adding a capture format"). Torch-free: cameras, poses and image paths as plain
// structs (no image is decoded) that Dataset::load (dataset.h) turns into tensors.
//
// One file per format, one row per format in capture.cpp's table (in detection order):
//   "blender"     transforms_{train,val,test}.json          transforms_json.cpp
//   "transforms"  instant-ngp / nerfstudio transforms.json  transforms_json.cpp
//   "colmap"      a COLMAP model (sparse/0, sparse, ...)    colmap_capture.cpp
//   "llff"        LLFF poses_bounds.npy                     llff_capture.cpp
// Every refusal is an InputError naming the file and the field; fuzz/fuzz_transforms.cpp fuzzes the
// readers.
#include <array>
#include <string>
#include <vector>

#include "data/camera.h"

namespace ablenerf {

// A camera-to-world pose: the top 3 rows of the 4x4 matrix, row-major (r * 4 + c), OpenGL axes.
// Checked finite and rigid (rotation orthonormal with det +1).
using Pose34 = std::array<float, 12>;

// How a frame's depth file holds its depth (Dataset::load makes both camera-space depth along -z).
enum class DepthFormat {
  Tensor,      // a pickled float tensor (H, W) of that depth (synth's r_N_depth.pt, depth_file_path)
  BlenderPng,  // nerf_synthetic's r_N_depth_0001.png (data/depth_file.h)
};

// The file beside a Blender frame's image that holds its depth, `<image stem>_depth_0001.png`
// (nerf_synthetic's test views; data/depth_file.h reads it), or "" when there is none.
std::string blender_depth_file(const std::string& image);

struct CaptureFrame {
  // Canonical path of the frame's image, inside the dataset folder: the pre-downscaled copy
  // (images_N/, see resolve_downscaled) when one matches the requested downscale.
  std::string image;
  bool prescaled = false;  // `image` is already downscaled (decoded as is, the camera scaled to its size)
  Intrinsics camera;       // at full resolution (width x height of Capture)
  std::string depth;       // canonical path of its depth file ("" when the frame has none)
  DepthFormat depth_format = DepthFormat::Tensor;
  std::string field;  // the field that names the image, e.g. "frames[3].file_path", for errors
  Pose34 pose{};
  // Canonical path of the frame's mask image ("" when none), at the capture's full size: which
  // pixels may train (Dataset::load, data.masks). Its first channel, thresholded at 128, says
  // "set"; with `mask_keeps_set` the set pixels train and the others are never drawn (nerfstudio's
  // mask_path, a masks/ folder: white keeps), without it the set pixels are the ones left out
  // (instant-ngp's dynamic_mask_*.png: anything non-black is a moving object).
  std::string mask;
  bool mask_keeps_set = true;
  std::string mask_field;  // the field or folder that named the mask, for errors
};

struct CaptureSplit {
  std::string name;  // train | val | test
  std::string file;  // the file the frames come from
  std::vector<CaptureFrame> frames;
};

// Everything Dataset::load reads from a capture folder.
struct Capture {
  // "blender" | "instant-ngp" | "nerfstudio" | "colmap" | "llff"
  std::string format;
  std::vector<CaptureSplit> splits;  // selected splits that have frames, in train, val, test order
  int width = 0, height = 0;         // full-resolution image size (every frame's)
  // What the capture says about the scene's extent, in the poses' units (empty / 0 when absent):
  std::vector<std::array<double, 3>> points;  // sparse points (COLMAP points3D)
  std::vector<std::array<double, 2>> bounds;  // near/far of every image of the capture (LLFF)
  double aabb_scale = 0;                      // instant-ngp's aabb_scale (> 1: content beyond the unit cube)
  bool synthetic = false;                     // Blender: a bounded object, near/far 2/6 by convention
  std::vector<std::string> notes;             // what was read, for `info` (one line each)

  // The names of the splits read, in order.
  std::vector<std::string> split_names() const;
};

// A row of the registry: `detect` says whether a folder holds this format (cheap: file names
// only); `read` fills a Capture with the `splits` wanted (empty = all) at `downscale` (>= 1: picks
// pre-downscaled images_N/ copies when present).
struct CaptureFormat {
  const char* name;
  bool (*detect)(const std::string& root);
  void (*read)(const std::string& root, const std::vector<std::string>& splits, int downscale, Capture& out);
};

// The registry, in detection order (the first whose detect is true reads the folder).
const std::vector<CaptureFormat>& capture_formats();

// The name of the format that would read `root` ("" when none).
std::string capture_format(const std::string& root);

// Reads the metadata of the capture folder `root` with its detected format; every frame's focal
// length checked positive. InputError naming the folder when no format matches.
Capture read_capture(const std::string& root, const std::vector<std::string>& splits, int downscale);

// --- shared by the format readers ---

// Frames held out as the test split of a capture without its own split: every 8th, sorted by
// image name (the LLFF / mip-NeRF 360 convention).
constexpr size_t kTestEvery = 8;

// True when `split` is among `splits` (empty = every split is wanted).
bool split_wanted(const std::vector<std::string>& splits, const std::string& split);

// Resolves a relative image path inside the dataset root (refusing paths that leave it or name no
// file) to its canonical path; `file`/`field` name it in errors. With `add_png` a path without an
// extension, or one that does not exist as written, gets ".png" (Blender's file_path convention).
std::string resolve_in_root(const std::string& root, const std::string& rel, const std::string& file,
                            const std::string& field, bool add_png = false);

// `image` (canonical, inside `root`) in the pre-downscaled folder for `downscale`: for
// ROOT/images/a/b.jpg, ROOT/images_N/a/b.jpg, or the same stem with another image extension
// (.png, .jpg, .jpeg, .JPG, .PNG; LLFF writes PNGs there). "" when there is none or downscale is 1.
std::string resolve_downscaled(const std::string& root, const std::string& image, int downscale);

// The mask of `image` (canonical, full-size, inside `root`, under ROOT/images/) in the capture's
// masks/ folder, the COLMAP / LLFF layout (also what nerfstudio's processing writes): for
// ROOT/images/a/b.jpg, ROOT/masks/a/b with any image extension (.png, .jpg, .jpeg, any case).
// "" when the capture has no masks/ folder; with one, an image without its mask is
// InputError(ROOT/masks, field, "no mask for ...").
std::string mask_in_folder(const std::string& root, const std::string& image, const std::string& field);

// The order split_every_eighth counts frames in: the file's (instant-ngp) or by image path (COLMAP,
// LLFF: the LLFF / mip-NeRF 360 convention).
enum class FrameOrder { AsGiven, ByImageName };

// Every kTestEvery-th frame of `all` (from 0, in `order`) to test, the rest to train (one frame:
// train only). Only the `splits` wanted are kept (empty = both).
void split_every_eighth(std::vector<CaptureFrame> all, const std::vector<std::string>& splits, const std::string& file,
                        FrameOrder order, Capture& out);

// Checks a camera-to-world pose (finite, rotation orthonormal with det +1) given as 3x4 doubles,
// row-major; returns it as a Pose34.
Pose34 checked_pose(const double (&m)[3][4], const std::string& file, const std::string& field);

// A focal length in pixels: positive and finite, since every ray direction divides by it.
void check_focal(double f, const std::string& file, const std::string& field);

}  // namespace ablenerf
