#pragma once
// `ablenerf export --points / --mesh` as a library call (docs/ARCHITECTURE.md, "Geometry out"): the
// run's model renders colour and depth (attention depth, docs/MODEL.md section 9) from the capture's
// own cameras; pixels where the attention picked one place (two of its depths agree) become
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
enum class DepthEstimate { Auto, Front, Mean };

// The picture `export` writes into the run folder by default (geometry/preview.h; the report shows it).
constexpr const char* kGeometryPreviewFile = "geometry_preview.png";
// Points drawn in the picture at most (evenly thinned).
constexpr int64_t kPreviewMaxPoints = 400000;

struct GeometryOptions {
  std::string points_path, mesh_path;  // what to write (at least one)
  std::string preview_path;            // a picture of the points and the cameras (.png); empty: none
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
  // Which attention depth becomes the surface (eval/renderer.h, AttentionDepth): the attention's
  // front (where its first 15% lie nearer: on the demo scene's spheres the mesh's F-score rose from
  // 0.20 to 0.72, docs/BENCHMARKS.md) or the weighted mean; Auto: the front, except for
  // forward-facing runs, the mean (measured on the forward-facing test capture: the front's points
  // lay 0.54 from the surfaces, the mean's 0.17; the front's case rests on bounded scenes).
  DepthEstimate depth = DepthEstimate::Auto;
  // A pixel counts where the attention looked at one place: its front and median depths (with the
  // front) or its mean and argmax depths (with the mean) agree within this share of the depth.
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
// bounded scenes, the contraction's linear unit region for unbounded ones (forward-facing ones:
// see export_geometry).
CropBox default_crop(const RunFolder& run, const SceneFrame& scene);

// Renders, fuses and writes; returns what was written (paths, counts, seconds) for the command's
// last line and the run's report (record_export). Forward-facing runs: the attention depth (the
// NDC ray's t') is turned into metric depth per pixel (model/ndc.h, depth_from_ndc) and the
// default crop is the box of the points themselves (the central 98% on each axis). InputError for
// a run without weights, an empty crop, or a resolution whose volume exceeds kMaxTsdfVoxels.
nlohmann::json export_geometry(const RunFolder& run, const GeometryOptions& opts);

// Adds export_geometry's result, with the time (UTC), to RUN/exports.json (a JSON array, written
// atomically), which the run's report lists (eval/report.h).
void record_export(const RunFolder& run, const nlohmann::json& result);

}  // namespace ablenerf
