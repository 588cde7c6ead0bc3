#pragma once
// Datasets: Blender scenes (transforms_{train,val,test}.json + PNGs) and real captures
// (instant-ngp / nerfstudio transforms.json, COLMAP models, LLFF poses_bounds.npy; PNG or JPEG;
// see capture.h). Images are decoded in parallel, box-downscaled in straight
// (non-premultiplied) RGBA (or read from a pre-downscaled images_N/ folder), composited on the
// background, and kept as one float tensor per split. A capture's poses are moved into its scene
// frame (scene_frame.h). Rays are generated on the fly from poses and per-image cameras (rays.h),
// never tabulated.
#include <torch/torch.h>

#include <map>
#include <optional>
#include <string>
#include <vector>

#include "data/capture.h"
#include "data/rays.h"
#include "data/scene_frame.h"
#include "data/data_config.h"

namespace ablenerf {

struct LoadOptions {
  int downscale = 1;
  bool white_background = true;
  double near = 2.0, far = 6.0;
  SceneKind scene = SceneKind::Auto;  // data.scene
  bool bounds_from_config = false;    // data.bounds_from_config
  bool ndc = true;                    // data.ndc
  SceneFrameOverrides frame;          // data.scene_centre, data.scene_radius
  // JPEGs loaded at 1/2, 1/4 or 1/8 (or a multiple) are decoded reduced inside libjpeg (its scaled
  // inverse DCT) instead of in full and then box-filtered: 4 to 20 times less work, a result within
  // about one 8-bit level of the box filter's (tests/data/dataset_test.cpp).
  bool jpeg_reduce = true;
  MaskSource masks = MaskSource::None;  // data.masks: which pixels train (Split::mask)
  // Print a progress line while decoding (the CLI's loads; tests keep quiet).
  bool progress = false;
  // Splits to decode; empty = all present. Others are still validated for pose/shape errors
  // only when listed.
  std::vector<std::string> splits;
  // Refuse to start when the decoded images would need more than this many bytes
  // (0 = use the machine's available memory).
  int64_t memory_limit_bytes = 0;
};

struct Split {
  std::string name;
  torch::Tensor images;  // (N,H,W,3) float32 in [0,1], composited on the background
  torch::Tensor alpha;   // (N,H,W) float32 alpha after downscale
  // (N,H,W) bool: the pixels that train and that eval scores as "unmasked" (LoadOptions::masks);
  // undefined when every pixel does. A loaded pixel stands for a box of full-size pixels: it is
  // kept when at least half of its box is (its mask's first channel averaged over the box, / 255,
  // at least 0.5 for masks that keep white, below 0.5 for instant-ngp's, which leave it out).
  torch::Tensor mask;
  torch::Tensor c2w;                // (N,3,4) float32 camera-to-world, OpenGL axes, in the scene frame
  std::vector<Intrinsics> cameras;  // each image's camera at the loaded resolution
  std::vector<std::string> files;   // image paths
  torch::Tensor
      depth;  // (N,H,W) float32 depth along the optical axis in scene units, if the dataset has it (else undefined)
  int64_t size() const { return c2w.defined() ? c2w.size(0) : 0; }
};

struct Dataset {
  std::string root;
  std::string format;            // "blender" | "instant-ngp" | "nerfstudio" | "colmap" | "llff"
  Intrinsics intrinsics;         // the first image's camera (every image's, unless the capture has per-image ones)
  double near = 2.0, far = 6.0;  // scene.near / scene.far
  SceneFrame scene;
  std::vector<std::string> notes;  // what the loader read and chose, for `info`
  double load_seconds = 0;
  std::map<std::string, Split> splits;

  bool has(const std::string& split) const { return splits.count(split) > 0; }
  const Split& split(const std::string& name) const;

  // Loads a dataset folder. Throws InputError naming the file and field on any bad input.
  static Dataset load(const std::string& root, const LoadOptions& opts = {});
  // Loads the splits opts.splits wants (empty = all) of a capture already read from `root`
  // (read_capture(root, {}, opts.downscale): its metadata is parsed once however many callers
  // look at it).
  static Dataset load(Capture capture, const std::string& root, const LoadOptions& opts);
};

// Below this many pixels on the short side a downscaled image keeps too little of a scene to learn
// its surfaces (a 100x100 render under the capture preset's factor 8 becomes 12x12): the loader
// then says so in Dataset::notes and the log, and trains as asked.
inline constexpr int kSmallImageSide = 64;
// That note for photos of full_h x full_w at `downscale`, or "" when the images stay large enough
// (or are not downscaled at all).
std::string small_image_note(int full_h, int full_w, int downscale);

// Reads a camera list (Blender/transforms json) for rendering: poses (N,3,4) and intrinsics,
// without loading images. `width`/`height` > 0 rescale the intrinsics to that size.
struct CameraList {
  torch::Tensor c2w;
  Intrinsics intrinsics;
};
CameraList load_cameras(const std::string& json_path, int width = 0, int height = 0);

// Every camera of a capture folder (any format; every split, in split order), poses moved into
// `scene`, intrinsics those of the first image at `downscale` (lens included). No image is decoded.
CameraList capture_cameras(const std::string& root, const SceneFrame& scene, int downscale);
// The same from metadata already read (read_capture(root, {}, downscale)).
CameraList capture_cameras(const Capture& capture, const SceneFrame& scene, int downscale);

// One frame's photo as the loader reads it: (h, w, 4) float straight RGBA (alpha 1 for RGB images),
// turned upright by its EXIF orientation when the capture's size says so, at the capture's size
// (full_h x full_w, Capture's) divided by `downscale`: box-downscaled, or the pre-downscaled
// images_N copy cropped. Bad image: InputError naming the file and its json field.
torch::Tensor frame_photo_rgba(const CaptureFrame& frame, int full_h, int full_w, int downscale);

// A pose as a (3,4) float32 tensor.
torch::Tensor pose_tensor(const Pose34& pose);

// Poses (N,3,4) given in a capture's own coordinates, moved into its scene frame.
torch::Tensor poses_to_scene(const torch::Tensor& c2w, const SceneFrame& scene);

}  // namespace ablenerf
