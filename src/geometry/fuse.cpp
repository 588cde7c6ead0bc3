#include "geometry/fuse.h"

#include <open3d/camera/PinholeCameraIntrinsic.h>
#include <open3d/geometry/BoundingVolume.h>
#include <open3d/geometry/Image.h>
#include <open3d/geometry/KDTreeSearchParam.h>
#include <open3d/geometry/PointCloud.h>
#include <open3d/geometry/RGBDImage.h>
#include <open3d/geometry/TriangleMesh.h>
#include <open3d/io/PointCloudIO.h>
#include <open3d/io/TriangleMeshIO.h>
#include <open3d/pipelines/integration/ScalableTSDFVolume.h>
#include <open3d/utility/Logging.h>

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <vector>
#include <filesystem>

#include "util/errors.h"
#include "util/fs.h"

namespace fs = std::filesystem;

namespace ablenerf {

namespace {

// Open3D writes its own warnings to standard output ("appears to be a PointCloud"), which would
// break a command's JSON result: only its errors are let through.
void quiet_open3d() {
  static const bool once = [] {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    return true;
  }();
  (void)once;
}

// Open3D's TSDF blocks: 16^3 voxels each (its default).
constexpr int kVolumeUnit = 16;

// World-to-camera in OpenCV axes (Open3D's extrinsic) from an OpenGL camera-to-world (3,4).
Eigen::Matrix4d extrinsic_of(const torch::Tensor& c2w) {
  const auto m = c2w.to(torch::kDouble).contiguous();
  const auto a = m.accessor<double, 2>();
  Eigen::Matrix4d cw = Eigen::Matrix4d::Identity();
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) cw(r, c) = a[r][c] * ((c == 1 || c == 2) ? -1.0 : 1.0);  // y, z flipped
  return cw.inverse();
}

open3d::geometry::Image float_image(const torch::Tensor& x, int channels) {
  open3d::geometry::Image im;
  const auto c = x.to(torch::kFloat).contiguous();
  im.Prepare(static_cast<int>(c.size(1)), static_cast<int>(c.size(0)), channels, 4);
  std::memcpy(im.data_.data(), c.data_ptr<float>(), im.data_.size());
  return im;
}

open3d::geometry::Image rgb8_image(const torch::Tensor& rgb) {
  open3d::geometry::Image im;
  const auto c = (rgb.clamp(0, 1) * 255).round().to(torch::kUInt8).contiguous();
  im.Prepare(static_cast<int>(c.size(1)), static_cast<int>(c.size(0)), 3, 1);
  std::memcpy(im.data_.data(), c.data_ptr<uint8_t>(), im.data_.size());
  return im;
}

Mesh mesh_from(const open3d::geometry::TriangleMesh& m) {
  Mesh out;
  const auto nv = static_cast<int64_t>(m.vertices_.size()), nt = static_cast<int64_t>(m.triangles_.size());
  out.vertices = torch::empty({nv, 3}, torch::kDouble);
  auto v = out.vertices.accessor<double, 2>();
  for (int64_t i = 0; i < nv; ++i)
    for (int j = 0; j < 3; ++j) v[i][j] = m.vertices_[static_cast<size_t>(i)](j);
  if (m.HasVertexColors()) {
    out.colours = torch::empty({nv, 3}, torch::kFloat);
    auto c = out.colours.accessor<float, 2>();
    for (int64_t i = 0; i < nv; ++i)
      for (int j = 0; j < 3; ++j) c[i][j] = static_cast<float>(m.vertex_colors_[static_cast<size_t>(i)](j));
  }
  out.triangles = torch::empty({nt, 3}, torch::kLong);
  auto t = out.triangles.accessor<int64_t, 2>();
  for (int64_t i = 0; i < nt; ++i)
    for (int j = 0; j < 3; ++j) t[i][j] = m.triangles_[static_cast<size_t>(i)](j);
  return out;
}

open3d::geometry::TriangleMesh open3d_mesh(const Mesh& in) {
  open3d::geometry::TriangleMesh m;
  const auto v = in.vertices.to(torch::kDouble).contiguous();
  const auto va = v.accessor<double, 2>();
  for (int64_t i = 0; i < v.size(0); ++i) m.vertices_.emplace_back(va[i][0], va[i][1], va[i][2]);
  if (in.colours.defined()) {
    const auto c = in.colours.to(torch::kDouble).contiguous();
    const auto ca = c.accessor<double, 2>();
    for (int64_t i = 0; i < c.size(0); ++i) m.vertex_colors_.emplace_back(ca[i][0], ca[i][1], ca[i][2]);
  }
  const auto t = in.triangles.to(torch::kLong).contiguous();
  const auto ta = t.accessor<int64_t, 2>();
  for (int64_t i = 0; i < t.size(0); ++i)
    m.triangles_.emplace_back(static_cast<int>(ta[i][0]), static_cast<int>(ta[i][1]), static_cast<int>(ta[i][2]));
  return m;
}

open3d::geometry::PointCloud open3d_points(const PointSet& p) {
  open3d::geometry::PointCloud pc;
  const auto x = p.xyz.to(torch::kDouble).contiguous();
  const auto xa = x.accessor<double, 2>();
  pc.points_.reserve(static_cast<size_t>(x.size(0)));
  for (int64_t i = 0; i < x.size(0); ++i) pc.points_.emplace_back(xa[i][0], xa[i][1], xa[i][2]);
  if (p.rgb.defined()) {
    const auto c = p.rgb.to(torch::kDouble).clamp(0, 1).contiguous();
    const auto ca = c.accessor<double, 2>();
    for (int64_t i = 0; i < c.size(0); ++i) pc.colors_.emplace_back(ca[i][0], ca[i][1], ca[i][2]);
  }
  if (p.normals.defined()) {
    const auto n = p.normals.to(torch::kDouble).contiguous();
    const auto na = n.accessor<double, 2>();
    for (int64_t i = 0; i < n.size(0); ++i) pc.normals_.emplace_back(na[i][0], na[i][1], na[i][2]);
  }
  return pc;
}

PointSet point_set(const open3d::geometry::PointCloud& pc) {
  const auto n = static_cast<int64_t>(pc.points_.size());
  PointSet out;
  out.xyz = torch::empty({n, 3}, torch::kFloat);
  out.rgb = torch::empty({n, 3}, torch::kFloat);
  auto x = out.xyz.accessor<float, 2>(), c = out.rgb.accessor<float, 2>();
  for (int64_t i = 0; i < n; ++i)
    for (int j = 0; j < 3; ++j) {
      x[i][j] = static_cast<float>(pc.points_[static_cast<size_t>(i)](j));
      c[i][j] = pc.HasColors() ? static_cast<float>(pc.colors_[static_cast<size_t>(i)](j)) : 0.f;
    }
  if (pc.HasNormals()) {
    out.normals = torch::empty({n, 3}, torch::kFloat);
    auto m = out.normals.accessor<float, 2>();
    for (int64_t i = 0; i < n; ++i)
      for (int j = 0; j < 3; ++j) m[i][j] = static_cast<float>(pc.normals_[static_cast<size_t>(i)](j));
  }
  return out;
}

// Removes triangles with a vertex outside `crop`, then connected pieces smaller than `min_share` of
// the largest, then unreferenced vertices.
void trim_mesh(open3d::geometry::TriangleMesh& m, const CropBox& crop, double min_share) {
  std::vector<bool> drop(m.triangles_.size(), false);
  for (size_t i = 0; i < m.triangles_.size(); ++i)
    for (int j = 0; j < 3; ++j) {
      const auto& v = m.vertices_[static_cast<size_t>(m.triangles_[i](j))];
      if (!crop.contains({v(0), v(1), v(2)})) drop[i] = true;
    }
  m.RemoveTrianglesByMask(drop);
  if (min_share > 0 && !m.triangles_.empty()) {
    const auto [cluster, sizes, areas] = m.ClusterConnectedTriangles();
    const size_t largest = *std::max_element(sizes.begin(), sizes.end());
    std::vector<bool> small(m.triangles_.size());
    for (size_t i = 0; i < cluster.size(); ++i)
      small[i] = static_cast<double>(sizes[static_cast<size_t>(cluster[i])]) < min_share * static_cast<double>(largest);
    m.RemoveTrianglesByMask(small);
  }
  m.RemoveUnreferencedVertices();
}

// Writes through `write(tmp)` to the project's temporary name for `path` (util/fs.h's
// atomic_temp_prefix, so a killed export leaves what `RunFolder::remove_stale_temporaries` knows)
// with `path`'s extension (Open3D picks the format by it), then renames it over `path`. The folder
// was checked by check_points_path / check_mesh_path.
template <class Write>
void write_atomic(const std::string& path, Write write) {
  const std::string tmp = atomic_temp_prefix(path) + std::to_string(::getpid()) + fs::path(path).extension().string();
  if (!write(tmp)) {
    std::error_code ec;
    fs::remove(tmp, ec);
    throw EnvironmentError(path, "could not be written", "check the folder's permissions and free space");
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    const int err = errno;
    std::error_code ec;
    fs::remove(tmp, ec);
    throw write_error(path, err);
  }
}

std::string lower_extension(const std::string& path) {
  std::string e = fs::path(path).extension().string();
  std::transform(e.begin(), e.end(), e.begin(), [](unsigned char ch) { return static_cast<char>(std::tolower(ch)); });
  return e;
}

}  // namespace

Mesh fuse_tsdf(const std::vector<DepthView>& views, const TsdfOptions& opts) {
  quiet_open3d();
  open3d::pipelines::integration::ScalableTSDFVolume volume(
      opts.voxel, opts.truncation, open3d::pipelines::integration::TSDFVolumeColorType::RGB8, kVolumeUnit);
  for (const auto& v : views) {
    const auto depth = float_image(torch::nan_to_num(v.depth, 0.0).clamp_min(0), 1);
    const auto colour = rgb8_image(v.rgb);
    const auto rgbd =
        open3d::geometry::RGBDImage::CreateFromColorAndDepth(colour, depth, /*depth_scale=*/1.0, opts.max_depth,
                                                             /*convert_rgb_to_intensity=*/false);
    const open3d::camera::PinholeCameraIntrinsic k(v.camera.width, v.camera.height, v.camera.fx, v.camera.fy,
                                                   v.camera.cx, v.camera.cy);
    volume.Integrate(*rgbd, k, extrinsic_of(v.c2w));
  }
  auto mesh = volume.ExtractTriangleMesh();
  trim_mesh(*mesh, opts.crop, opts.min_island_share);
  return mesh_from(*mesh);
}

Mesh poisson_mesh(const PointSet& points, int depth, double trim, const CropBox& crop) {
  quiet_open3d();
  if (!points.normals.defined()) throw std::invalid_argument("poisson_mesh: the points need normals");
  const auto pc = open3d_points(points);
  auto [mesh, density] = open3d::geometry::TriangleMesh::CreateFromPointCloudPoisson(pc, static_cast<size_t>(depth));
  if (trim > 0 && !density.empty()) {
    std::vector<double> sorted = density;
    const size_t q = std::min(sorted.size() - 1, static_cast<size_t>(trim * static_cast<double>(sorted.size())));
    std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(q), sorted.end());
    const double cut = sorted[q];
    std::vector<bool> low(density.size());
    for (size_t i = 0; i < density.size(); ++i) low[i] = density[i] < cut;
    mesh->RemoveVerticesByMask(low);
  }
  trim_mesh(*mesh, crop, 0.0);
  return mesh_from(*mesh);
}

PointSet clean_points(const PointSet& points, int64_t max_points, int neighbours, double std_ratio,
                      const torch::Tensor& towards) {
  quiet_open3d();
  if (points.size() == 0) return points;
  // Each point's camera rides along as its normal until normals are estimated (Open3D keeps a
  // point's normal with it through outlier removal and thinning).
  PointSet carrier = points;
  if (towards.defined()) carrier.normals = towards;
  const auto pc = open3d_points(carrier);
  std::shared_ptr<open3d::geometry::PointCloud> kept;
  if (points.size() > neighbours) {
    kept = std::get<0>(pc.RemoveStatisticalOutliers(static_cast<size_t>(neighbours), std_ratio));
  } else {
    kept = std::make_shared<open3d::geometry::PointCloud>(pc);
  }
  if (max_points > 0 && static_cast<int64_t>(kept->points_.size()) > max_points) {
    // The voxel whose grid leaves about max_points: grow it from the box's size until it does.
    const auto box = kept->GetAxisAlignedBoundingBox();
    const double extent = std::max(box.GetExtent().maxCoeff(), 1e-9);
    double voxel = extent / std::cbrt(static_cast<double>(max_points)) / 4;
    auto thin = kept->VoxelDownSample(voxel);
    while (static_cast<int64_t>(thin->points_.size()) > max_points) {
      voxel *= 1.25;
      thin = kept->VoxelDownSample(voxel);
    }
    kept = thin;
  }
  std::vector<Eigen::Vector3d> cameras;
  if (towards.defined()) cameras = kept->normals_;
  kept->normals_.clear();
  kept->EstimateNormals(open3d::geometry::KDTreeSearchParamKNN(std::max(neighbours, 3)));
  if (!cameras.empty())
    for (size_t i = 0; i < kept->normals_.size(); ++i)
      if (kept->normals_[i].dot(cameras[i] - kept->points_[i]) < 0) kept->normals_[i] *= -1.0;
  return point_set(*kept);
}

static void check_output_folder(const std::string& path) {
  const fs::path p(path);
  if (!p.parent_path().empty() && !fs::is_directory(p.parent_path()))
    throw EnvironmentError(path, "folder " + p.parent_path().string() + " does not exist", "create it first");
}

void check_points_path(const std::string& path) {
  if (lower_extension(path) != ".ply") throw InputError(path, "--points", "point clouds are written as .ply");
  check_output_folder(path);
}

void check_mesh_path(const std::string& path) {
  const std::string e = lower_extension(path);
  if (e != ".ply" && e != ".obj" && e != ".glb" && e != ".gltf")
    throw InputError(path, "--mesh", "meshes are written as .ply, .obj or .glb");
  check_output_folder(path);
}

PointSet read_geometry_points(const std::string& path, int64_t mesh_samples) {
  quiet_open3d();
  if (!fs::is_regular_file(path)) throw InputError(path, "", "file not found");
  open3d::geometry::TriangleMesh mesh;
  open3d::io::ReadTriangleMeshOptions mo;
  if (open3d::io::ReadTriangleMesh(path, mesh, mo) && !mesh.triangles_.empty()) {
    const auto sampled = mesh.SamplePointsUniformly(static_cast<size_t>(mesh_samples));
    return point_set(*sampled);
  }
  open3d::geometry::PointCloud pc;
  if (!open3d::io::ReadPointCloud(path, pc) || pc.points_.empty())
    throw InputError(path, "", "no points or triangles could be read (PLY, OBJ or glTF expected)");
  return point_set(pc);
}

torch::Tensor nearest_distances(const torch::Tensor& from, const torch::Tensor& to) {
  if (to.size(0) == 0) return torch::full({from.size(0)}, INFINITY, torch::kDouble);
  if (from.size(0) == 0) return torch::empty({0}, torch::kDouble);
  PointSet a, b;
  a.xyz = from.reshape({-1, 3});
  b.xyz = to.reshape({-1, 3});
  return torch::tensor(open3d_points(a).ComputePointCloudDistance(open3d_points(b)), torch::kDouble);
}

std::vector<torch::Tensor> mesh_depth_maps(const std::string& path,
                                           const std::vector<std::pair<torch::Tensor, Intrinsics>>& cameras) {
  quiet_open3d();
  if (!fs::is_regular_file(path)) throw InputError(path, "", "file not found");
  open3d::geometry::TriangleMesh mesh;
  open3d::io::ReadTriangleMeshOptions mo;
  if (!open3d::io::ReadTriangleMesh(path, mesh, mo) || mesh.triangles_.empty()) return {};
  std::vector<torch::Tensor> out;
  for (const auto& [pose, k] : cameras) {
    const auto c2w = pose.to(torch::kDouble).contiguous();
    const auto m = c2w.accessor<double, 2>();
    // Camera coordinates of every vertex: R^T (p - c); the image point (X, Y) with pixel centres at
    // col + 0.5, row + 0.5 (data/rays.h casts (X - cx) / fx, -(Y - cy) / fy, -1).
    const size_t nv = mesh.vertices_.size();
    std::vector<double> px(nv), py(nv), pz(nv);
    for (size_t v = 0; v < nv; ++v) {
      double d[3], c[3];
      for (int a = 0; a < 3; ++a) d[a] = mesh.vertices_[v][a] - m[a][3];
      for (int a = 0; a < 3; ++a) c[a] = m[0][a] * d[0] + m[1][a] * d[1] + m[2][a] * d[2];
      pz[v] = -c[2];
      px[v] = k.fx * c[0] / pz[v] + k.cx;
      py[v] = -k.fy * c[1] / pz[v] + k.cy;
    }
    auto depth = torch::full({k.height, k.width}, INFINITY, torch::kFloat);
    auto z = depth.accessor<float, 2>();
    for (const auto& t : mesh.triangles_) {
      const int a = t[0], b = t[1], c = t[2];
      if (pz[a] <= 1e-9 || pz[b] <= 1e-9 || pz[c] <= 1e-9) continue;
      const double area = (px[b] - px[a]) * (py[c] - py[a]) - (px[c] - px[a]) * (py[b] - py[a]);
      if (area == 0) continue;
      const int c0 = std::max(0, static_cast<int>(std::floor(std::min({px[a], px[b], px[c]}) - 0.5)));
      const int c1 = std::min(k.width - 1, static_cast<int>(std::ceil(std::max({px[a], px[b], px[c]}) - 0.5)));
      const int r0 = std::max(0, static_cast<int>(std::floor(std::min({py[a], py[b], py[c]}) - 0.5)));
      const int r1 = std::min(k.height - 1, static_cast<int>(std::ceil(std::max({py[a], py[b], py[c]}) - 0.5)));
      for (int row = r0; row <= r1; ++row)
        for (int col = c0; col <= c1; ++col) {
          const double x = col + 0.5, y = row + 0.5;
          // Barycentric weights from the signed areas opposite each corner.
          const double wa = ((px[b] - x) * (py[c] - y) - (px[c] - x) * (py[b] - y)) / area;
          const double wb = ((px[c] - x) * (py[a] - y) - (px[a] - x) * (py[c] - y)) / area;
          const double wc = 1.0 - wa - wb;
          if (wa < 0 || wb < 0 || wc < 0) continue;
          const double d = 1.0 / (wa / pz[a] + wb / pz[b] + wc / pz[c]);
          if (d < z[row][col]) z[row][col] = static_cast<float>(d);
        }
    }
    out.push_back(depth);
  }
  return out;
}

void write_points(const PointSet& points, const std::string& path) {
  quiet_open3d();
  check_points_path(path);
  const auto pc = open3d_points(points);
  write_atomic(path, [&](const std::string& tmp) {
    return open3d::io::WritePointCloud(tmp, pc, open3d::io::WritePointCloudOption(/*ascii=*/false));
  });
}

void write_mesh(const Mesh& mesh, const std::string& path) {
  quiet_open3d();
  check_mesh_path(path);
  const auto m = open3d_mesh(mesh);
  write_atomic(path, [&](const std::string& tmp) {
    return open3d::io::WriteTriangleMesh(tmp, m, /*write_ascii=*/false, /*compressed=*/false,
                                         /*write_vertex_normals=*/false, /*write_vertex_colors=*/m.HasVertexColors(),
                                         /*write_triangle_uvs=*/false, /*print_progress=*/false);
  });
}

}  // namespace ablenerf
