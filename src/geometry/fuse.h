#pragma once
// Depth maps to meshes and point clouds to files, with Open3D (Debian's libopen3d-dev): a TSDF
// volume fused from depth maps and meshed by marching cubes (Curless and Levoy 1996, as Open3D's
// ScalableTSDFVolume does it), Poisson reconstruction from oriented points (Kazhdan et al. 2006),
// statistical outlier removal, voxel thinning and normals for point clouds, and the PLY / OBJ /
// glTF writers. Files are written under a temporary name and renamed, so a failed export never
// leaves a half-written file. Only this file and fuse.cpp see Open3D.
#include <torch/torch.h>

#include <string>
#include <vector>

#include "data/camera.h"
#include "geometry/depth_points.h"

namespace ablenerf {

// One view for fusion: a (3,4) camera-to-world pose (OpenGL axes, scene frame), its camera, its
// depth along the optical axis (H,W) (0 = unknown) and colour (H,W,3) in [0,1].
struct DepthView {
  torch::Tensor c2w, depth, rgb;
  Intrinsics camera;
};

struct Mesh {
  torch::Tensor vertices;   // (V,3) float64
  torch::Tensor colours;    // (V,3) float in [0,1] (may be undefined)
  torch::Tensor triangles;  // (T,3) int64
  int64_t vertex_count() const { return vertices.defined() ? vertices.size(0) : 0; }
  int64_t triangle_count() const { return triangles.defined() ? triangles.size(0) : 0; }
};

struct TsdfOptions {
  double voxel = 0.01;       // voxel side (scene units)
  double truncation = 0.04;  // signed-distance truncation (scene units), a few voxels
  double max_depth = 1e9;    // depths beyond this are not integrated
  CropBox crop;              // triangles with a vertex outside are dropped
  // Connected pieces with fewer triangles than this share of the largest piece are removed.
  double min_island_share = 0.01;
};

// Fuses the views into a TSDF volume and extracts its zero crossing with marching cubes; vertex
// colours are the fused colours.
Mesh fuse_tsdf(const std::vector<DepthView>& views, const TsdfOptions& opts);

// Poisson surface reconstruction of oriented points (normals required) at octree `depth`;
// vertices whose estimated point density is below the `trim` quantile are removed, then what
// lies outside `crop`.
Mesh poisson_mesh(const PointSet& points, int depth, double trim, const CropBox& crop);

// Statistical outlier removal (each point's mean distance to its `neighbours` nearest against the
// mean and deviation over all points), then even thinning: a voxel grid coarse enough to leave
// at most `max_points`, then normals estimated from the neighbours and turned towards `towards`
// (each point's camera; (N,3)) when given.
PointSet clean_points(const PointSet& points, int64_t max_points, int neighbours, double std_ratio,
                      const torch::Tensor& towards = {});

// Writers, by the path's extension: points to .ply; meshes to .ply, .obj or .glb (.gltf).
// InputError naming the path for an extension Open3D does not write; EnvironmentError when the
// file cannot be written (a missing folder, no permission, a full disk).
void write_points(const PointSet& points, const std::string& path);
void write_mesh(const Mesh& mesh, const std::string& path);
// The points of a geometry file for scoring: a mesh's surface sampled uniformly (`mesh_samples`
// points; Open3D reads .ply, .obj, .glb), else the file's points. InputError naming the path when it
// cannot be read or holds nothing.
PointSet read_geometry_points(const std::string& path, int64_t mesh_samples);

// Nearest-neighbour distance from each row of `from` (K,3) to the rows of `to` (N,3), float64 (K):
// Open3D's k-d tree (PointCloud::ComputePointCloudDistance), exact; infinity when `to` is empty.
torch::Tensor nearest_distances(const torch::Tensor& from, const torch::Tensor& to);

// Depth maps of the triangle mesh in `path` as pinhole cameras see it: for each camera (c2w (3,4),
// OpenGL axes; k without lens distortion) the camera-space depth along -z of the nearest triangle at
// each pixel centre, (k.height, k.width) float, infinity where there is none. A z-buffer, the depth
// interpolated perspective-correctly (1/z linear on the image); triangles reaching behind the camera
// are left out. (Open3D's ray casting, t::geometry::RaycastingScene, returns no hits at all in
// Debian's build 0.16.1: not even for a ray straight at a square.) An empty vector when the file
// holds no triangles (a point cloud); InputError naming the path when it cannot be read.
std::vector<torch::Tensor> mesh_depth_maps(const std::string& path,
                                           const std::vector<std::pair<torch::Tensor, Intrinsics>>& cameras);

// The same refusals before any work: `option` names the path's option.
void check_points_path(const std::string& path);
void check_mesh_path(const std::string& path);

}  // namespace ablenerf
