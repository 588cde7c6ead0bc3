#pragma once
// `ablenerf export --points / --mesh` as a library call (docs/ARCHITECTURE.md, "Geometry out"): the
// run's model renders colour and depth (attention depth, docs/MODEL.md section 9) from the capture's
// own cameras; pixels whose mean and argmax depths agree (the attention picked one place) become
// points, which are cleaned and thinned (fuse.h), or their depth maps are fused into a TSDF and
// meshed, or the oriented points are meshed by Poisson reconstruction. Everything is computed in
// the run's scene frame and written in the capture's own coordinates (or the scene frame).
#include <torch/torch.h>

#include <optional>
#include <string>

#include <nlohmann/json.hpp>

#include "geometry/depth_points.h"
#include "run/run_folder.h"

namespace ablenerf {

enum class MeshMethod { Tsdf, Poisson };

struct GeometryOptions {
  std::string points_path, mesh_path;  // what to write (at least one)
  int64_t num_points = 1'000'000;      // points kept at most (evenly thinned)
  // TSDF voxels along the crop box's longest side; 0 = auto: voxels 1.5 times the rendered pixels'
  // footprint at the median depth (finer voxels than the depth maps resolve fuse their noise into
  // layers), at most 512 along the box.
  int resolution = 0;
  MeshMethod method = MeshMethod::Tsdf;
  std::optional<CropBox> crop;  // in the output frame; default: the region the cameras look at
  bool scene_frame = false;     // write in the normalised scene frame instead of the capture's
  int64_t views = 48;           // cameras rendered at most (evenly over the capture's)
  int max_side = 200;           // rendered images' longest side at most (pixels)
  // Mean and argmax attention depths must agree within this share of the depth for a pixel to count.
  double agreement = 0.05;
  // Use the photos' alpha where they have one (Blender's RGBA renders): transparent pixels are
  // background and give no geometry.
  bool alpha_mask = true;
  int64_t chunk = 4096;
  torch::Device device = torch::kCPU;
  bool progress = true;
};

// Largest TSDF volume accepted (voxels of the crop box): refused before anything is allocated.
constexpr double kMaxTsdfVoxels = 1024.0 * 1024.0 * 1024.0;

// The region the cameras look at, in the scene frame: Blender's object box (model.grid_bound) for
// bounded scenes, the contraction's linear unit region for unbounded ones.
CropBox default_crop(const RunFolder& run, const SceneFrame& scene);

// Renders, fuses and writes; returns what was written (paths, counts, seconds) for the command's
// last line and the run's report. InputError for a run without weights, a forward-facing run (its
// depth is NDC's), an empty crop, or a resolution whose volume exceeds kMaxTsdfVoxels.
nlohmann::json export_geometry(const RunFolder& run, const GeometryOptions& opts);

}  // namespace ablenerf
