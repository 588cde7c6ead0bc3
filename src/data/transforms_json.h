#pragma once
// The json half of the dataset loader, without LibTorch: parses and validates Blender
// transforms_{train,val,test}.json and instant-ngp / nerfstudio transforms.json files, resolves
// every frame's image path inside the dataset folder, and returns plain structs. Dataset::load
// and load_cameras (dataset.h) turn them into tensors; fuzz/fuzz_transforms.cpp fuzzes them.
// Every refusal is an InputError naming the file and the json field.
#include <array>
#include <string>
#include <vector>

namespace ablenerf {

// A camera-to-world pose: the top 3 rows of the 4x4 matrix, row-major (r * 4 + c), OpenGL axes.
// Checked finite and rigid (rotation orthonormal with det +1).
using Pose34 = std::array<float, 12>;

struct FrameJson {
  std::string image;  // canonical path of the frame's image, inside the dataset folder
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
  std::string format;  // "blender" | "transforms"
  std::vector<SplitJson> splits;  // selected splits that have frames, in train, val, test order
  int width = 0, height = 0;      // full-resolution image size
  double fx = 0, fy = 0;          // focal lengths in pixels at the downscaled resolution (> 0)
  double cx = -1, cy = -1;        // principal point at the downscaled resolution; -1 = image centre
};

// Reads the json of the dataset folder `root`: Blender transforms_*.json when a train or test file
// exists, else one transforms.json (every 8th frame held out as the test split). `splits` selects
// the splits to read (empty = all present); `downscale` (>= 1) scales the intrinsics.
DatasetJson read_dataset_json(const std::string& root, const std::vector<std::string>& splits, int downscale);

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
