#pragma once
// The metadata half of the dataset loader, without LibTorch: reads a capture's cameras, poses and
// image paths (no image is decoded) from whichever format the folder holds and returns plain
// structs that Dataset::load (dataset.h) turns into tensors. One reader per format:
//   Blender transforms_{train,val,test}.json and instant-ngp / nerfstudio transforms.json (here),
//   a COLMAP model (colmap_capture.cpp), LLFF poses_bounds.npy (llff_capture.cpp).
// fuzz/fuzz_transforms.cpp fuzzes the json readers. Every refusal is an InputError naming the file
// and the field.
#include <array>
#include <string>
#include <vector>

#include "data/camera.h"

namespace ablenerf {

// A camera-to-world pose: the top 3 rows of the 4x4 matrix, row-major (r * 4 + c), OpenGL axes.
// Checked finite and rigid (rotation orthonormal with det +1).
using Pose34 = std::array<float, 12>;

struct FrameJson {
  // Canonical path of the frame's image, inside the dataset folder: the pre-downscaled copy
  // (images_N/, see resolve_downscaled) when one matches the requested downscale.
  std::string image;
  bool prescaled = false;  // `image` is already downscaled (decoded as is, the camera scaled to its size)
  Intrinsics camera;  // at full resolution (width x height of DatasetJson)
  std::string depth;  // canonical path of its depth tensor ("" when the frame has none)
  std::string field;  // json field of the image path, e.g. "frames[3].file_path", for errors
  Pose34 pose{};
};

struct SplitJson {
  std::string name;  // train | val | test
  std::string file;  // the json file the frames come from
  std::vector<FrameJson> frames;
};

// Everything Dataset::load reads from a folder's json files; no image is decoded (for the
// Blender format the image size comes from the first frame's PNG header).
struct DatasetJson {
  // "blender" | "instant-ngp" | "nerfstudio" | "colmap" | "llff"
  std::string format;
  std::vector<SplitJson> splits;  // selected splits that have frames, in train, val, test order
  int width = 0, height = 0;      // full-resolution image size (every frame's)
  // What the capture says about the scene's extent, in the poses' units (empty / 0 when absent):
  std::vector<std::array<double, 3>> points;   // sparse points (COLMAP points3D)
  std::vector<std::array<double, 2>> bounds;   // near/far of every image of the capture (LLFF)
  double aabb_scale = 0;                       // instant-ngp's aabb_scale (> 1: content beyond the unit cube)
  bool synthetic = false;                      // Blender: a bounded object, near/far 2/6 by convention
  std::vector<std::string> notes;              // what was read, for `info` (one line each)
};

// Frames held out as the test split of a capture without its own split: every 8th, sorted by
// image name (the LLFF / mip-NeRF 360 convention).
constexpr size_t kTestEvery = 8;

// Reads the metadata of the dataset folder `root`, detecting the format: Blender when a
// transforms_train.json or transforms_test.json exists, else transforms.json (instant-ngp or
// nerfstudio), else a COLMAP model (sparse/0/, sparse/ or the folder itself holding cameras.bin or
// cameras.txt), else LLFF poses_bounds.npy. `splits` selects the splits to read (empty = all
// present); `downscale` (>= 1) picks pre-downscaled images (images_N/) when present.
DatasetJson read_dataset_json(const std::string& root, const std::vector<std::string>& splits, int downscale);

// The format read_dataset_json would read in `root` ("" when none).
std::string detect_format(const std::string& root);

// --- shared by the format readers ---

// `image` (canonical, inside `root`) in the pre-downscaled folder for `downscale`: for
// ROOT/images/a/b.jpg, ROOT/images_N/a/b.jpg, or the same stem with another image extension
// (.png, .jpg, .jpeg, .JPG, .PNG; LLFF writes PNGs there). "" when there is none or downscale is 1.
std::string resolve_downscaled(const std::string& root, const std::string& image, int downscale);

// The order split_every_eighth counts frames in: the file's (instant-ngp) or by image path (COLMAP,
// LLFF: the LLFF / mip-NeRF 360 convention).
enum class FrameOrder { AsGiven, ByImageName };

// Every kTestEvery-th frame of `all` (from 0, in `order`) to test, the rest to train (one frame:
// train only). Only the `splits` wanted are kept (empty = both).
void split_every_eighth(std::vector<FrameJson> all, const std::vector<std::string>& splits, const std::string& file,
                        FrameOrder order, DatasetJson& out);

// Resolves a relative image path inside the dataset root (refusing paths that leave it) to its
// canonical path; `file`/`field` name it in errors.
std::string resolve_in_root(const std::string& root, const std::string& rel, const std::string& file,
                            const std::string& field);

// Checks a camera-to-world pose (finite, rotation orthonormal with det +1) given as 3x4 doubles,
// row-major; returns it as a Pose34.
Pose34 checked_pose(const double (&m)[3][4], const std::string& file, const std::string& field);

// Readers of the other formats (colmap_capture.cpp, llff_capture.cpp).
void read_colmap_capture(const std::string& root, const std::string& model_dir, const std::vector<std::string>& splits,
                         int downscale, DatasetJson& out);
void read_llff_capture(const std::string& root, const std::vector<std::string>& splits, int downscale, DatasetJson& out);

// A camera list for rendering: poses and pinhole intrinsics, no image paths.
struct CameraJson {
  double fx = 0, fy = 0, cx = 0, cy = 0;
  int width = 0, height = 0;
  std::vector<Pose34> poses;  // at least one
};

// Reads a Blender/transforms json as a camera list. `width`/`height` > 0 rescale the intrinsics
// to that image size; without them the json must give w and h.
CameraJson read_camera_json(const std::string& path, int width = 0, int height = 0);

}  // namespace ablenerf
