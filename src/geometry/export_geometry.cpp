#include "geometry/export_geometry.h"

#include <chrono>
#include <ctime>
#include <cmath>
#include <filesystem>

#include "data/dataset.h"
#include "eval/renderer.h"
#include "geometry/fuse.h"
#include "geometry/preview.h"
#include "model/ndc.h"
#include "data/rays.h"
#include "util/errors.h"
#include "util/fs.h"
#include "util/image_io.h"
#include "util/progress.h"
#include "data/data_config.h"
#include "model/model_config.h"

namespace fs = std::filesystem;

namespace ablenerf {

namespace {

// A run whose depth maps gave no surface point at all (an early run): the run is named, not a flag.
InputError export_no_surface_error() {
  return InputError("export", "--run",
                    "the run's depth maps hold no surface point (a run this early has none yet: train it longer)");
}

// Outlier removal: each point against its 20 nearest, dropped beyond 2 deviations (Open3D's usual).
constexpr int kOutlierNeighbours = 20;
constexpr double kOutlierStdRatio = 2.0;
// Poisson: octree depth 9 (512 cells per side), vertices below the 5% density quantile trimmed.
constexpr int kPoissonDepth = 9;
constexpr double kPoissonTrim = 0.05;
// Auto TSDF voxel: this many rendered pixels' footprints at the median depth, no finer than the
// crop box's longest side / kMaxAutoResolution.
constexpr double kAutoFootprints = 1.5;
constexpr double kMaxAutoResolution = 512;
// TSDF truncation in voxels.
constexpr double kTruncationVoxels = 4.0;
// Forward-facing runs: NDC depths are read no farther than t' = 0.999 (1000 near planes away), and
// the default crop is the box of the central 98% of the points per axis, 5% wider on every side.
constexpr double kMaxNdcT = 0.999;
constexpr double kForwardBoxShare = 0.98;
constexpr double kForwardBoxMargin = 0.05;

double seconds_since(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

// The box of the output frame's crop in the scene frame: the bounds of its 8 corners moved there.
CropBox scene_box_of(const CropBox& out_box, const SceneFrame& scene, bool scene_frame) {
  if (scene_frame) return out_box;
  CropBox b;
  b.lo = {1e300, 1e300, 1e300};
  b.hi = {-1e300, -1e300, -1e300};
  for (int corner = 0; corner < 8; ++corner) {
    const std::array<double, 3> p{corner & 1 ? out_box.hi[0] : out_box.lo[0],
                                  corner & 2 ? out_box.hi[1] : out_box.lo[1],
                                  corner & 4 ? out_box.hi[2] : out_box.lo[2]};
    const auto s = scene.point_to_scene(p);
    for (size_t i = 0; i < 3; ++i) b.lo[i] = std::min(b.lo[i], s[i]), b.hi[i] = std::max(b.hi[i], s[i]);
  }
  return b;
}

// Keeps the rows of `xyz` (and their colours/normals) inside `box`.
PointSet crop_points(const PointSet& p, const CropBox& box) {
  if (p.size() == 0) return p;
  const auto idx = box.inside(p.xyz).nonzero().squeeze(-1);
  PointSet out{p.xyz.index_select(0, idx), p.rgb.index_select(0, idx), {}};
  if (p.normals.defined()) out.normals = p.normals.index_select(0, idx);
  return out;
}

// The photo's alpha resampled to the rendered size (area average), or undefined when the photo is
// opaque everywhere (JPEGs, RGB PNGs): decoded at the largest downscale that keeps it at least that size.
torch::Tensor photo_alpha(const CaptureFrame& frame, const Capture& capture, const Intrinsics& k) {
  const int downscale = std::max(1, std::min(capture.width / k.width, capture.height / k.height));
  const auto rgba = frame_photo_rgba(frame, capture.height, capture.width, downscale);
  const auto alpha = rgba.select(-1, 3).to(torch::kFloat);
  if (alpha.min().item<float>() >= 1.0f) return {};
  return torch::nn::functional::interpolate(alpha.unsqueeze(0).unsqueeze(0),
                                            torch::nn::functional::InterpolateFuncOptions()
                                                .size(std::vector<int64_t>{k.height, k.width})
                                                .mode(torch::kArea))
      .squeeze(0)
      .squeeze(0);
}

// Refuses a TSDF resolution whose volume over `box` would not fit (before anything is allocated).
void check_tsdf_volume(const GeometryOptions& opts, const CropBox& box) {
  if (opts.mesh_path.empty() || opts.method != MeshMethod::Tsdf || opts.resolution == 0) return;
  const double longest = std::max({box.hi[0] - box.lo[0], box.hi[1] - box.lo[1], box.hi[2] - box.lo[2]});
  const double voxel = longest / std::max(opts.resolution, 1);
  double voxels = 1;
  for (size_t i = 0; i < 3; ++i) voxels *= std::ceil((box.hi[i] - box.lo[i]) / voxel);
  if (opts.resolution < 8 || voxels > kMaxTsdfVoxels)
    throw InputError("export", "--resolution",
                     std::to_string(opts.resolution) + " gives a volume of " + std::to_string(voxels) +
                         " voxels; use 8 to " + std::to_string(static_cast<int>(std::cbrt(kMaxTsdfVoxels))));
}

}  // namespace

CropBox default_crop(const RunFolder& run, const SceneFrame& scene) {
  CropBox b;
  const double half = scene.kind == SceneKind::Unbounded ? 1.0 : run.config.get<ModelConfig>().grid_bound;
  b.lo = {-half, -half, -half};
  b.hi = {half, half, half};
  return b;
}

nlohmann::json export_geometry(const RunFolder& run, const GeometryOptions& opts) {
  const auto start = std::chrono::steady_clock::now();
  if (opts.points_path.empty() && opts.mesh_path.empty())
    throw InputError("export", "--points", "give --points FILE.ply and/or --mesh FILE.ply|.obj|.glb");
  if (!opts.points_path.empty()) check_points_path(opts.points_path);
  if (!opts.mesh_path.empty()) check_mesh_path(opts.mesh_path);
  if (!opts.preview_path.empty() && fs::path(opts.preview_path).extension() != ".png")
    throw InputError("export", "--preview", "'" + opts.preview_path + "': the picture is a .png");
  if (!fs::exists(run.weights_path()))
    throw InputError(run.weights_path(), "", "the run has no weights (train it first)");
  if (run.data_dir.empty())
    throw InputError(run.path("run.json"), "data", "no dataset recorded: its cameras are needed");
  const SceneFrame scene = run.scene();
  // Forward-facing runs see depth as the NDC ray's t' (model/ndc.h): turned into metric depth per
  // pixel below, and their crop box, unless given, is the one that holds the geometry itself.
  const bool forward = scene.kind == SceneKind::ForwardFacing;
  const bool box_from_points = forward && !opts.crop;
  const bool use_front = opts.depth == DepthEstimate::Front || (opts.depth == DepthEstimate::Auto && !forward);
  // (A forward-facing box from the points is set once they are known; until then nothing is cropped.)
  CropBox scene_box = opts.crop         ? scene_box_of(*opts.crop, scene, opts.scene_frame)
                      : box_from_points ? CropBox{{-kUnboundedFar, -kUnboundedFar, -kUnboundedFar},
                                                  {kUnboundedFar, kUnboundedFar, kUnboundedFar}}
                                        : default_crop(run, scene);
  if (!box_from_points) check_tsdf_volume(opts, scene_box);

  // The cameras: every one of the capture's (all splits), evenly thinned to opts.views.
  const Capture capture = read_capture(run.data_dir, {}, 1);
  std::vector<const CaptureFrame*> frames;
  for (const auto& sp : capture.splits)
    for (const auto& f : sp.frames) frames.push_back(&f);
  CameraList cams = capture_cameras(capture, scene, run.config.get<DataConfig>().downscale);
  const int64_t n_all = cams.c2w.size(0);
  const int64_t n = std::min<int64_t>(n_all, std::max<int64_t>(opts.views, 1));
  Intrinsics k = cams.intrinsics;
  const int side = std::max(k.width, k.height);
  if (side > opts.max_side) {
    const double s = static_cast<double>(opts.max_side) / side;
    const int w = std::max(1, static_cast<int>(std::lround(k.width * s))),
              h = std::max(1, static_cast<int>(std::lround(k.height * s)));
    k = k.scaled(static_cast<double>(w) / k.width, w, h);
  }
  AbleNerf model = load_run_model(run, opts.device);

  std::vector<PointSet> sets;
  std::vector<torch::Tensor> eyes;  // each point's camera centre, to orient its normal
  std::vector<DepthView> views;
  std::optional<Progress> progress;
  if (opts.progress) progress.emplace("export: render", n * k.width * k.height, 2.0);
  const auto render_start = std::chrono::steady_clock::now();
  for (int64_t v = 0; v < n; ++v) {
    const int64_t i = n == n_all ? v : v * n_all / n;
    const auto c2w = cams.c2w[i];
    const int64_t before = v * k.width * k.height;
    RenderResult r =
        render_image(model, c2w, k, scene.near, scene.far, opts.chunk, {}, opts.device, [&](int64_t done, int64_t) {
          if (progress) progress->update(before + done);
        });
    double near = scene.near, far = scene.far;
    if (forward) {
      const Rays rays = rays_for_image(c2w.to(torch::kDouble), k);
      // t' = 1 is infinity: pixels beyond kMaxNdcT (the sky) get depth 0, which gives no point.
      const auto metric = [&](const torch::Tensor& t) {
        const auto tc = t.reshape({-1}).to(torch::kDouble);
        const auto d = depth_from_ndc(rays, tc.clamp(0.0, kMaxNdcT));
        return torch::where(tc <= kMaxNdcT, d, torch::zeros_like(d)).reshape(t.sizes()).to(torch::kFloat);
      };
      r.depth_mean = metric(r.depth_mean);
      r.depth_argmax = metric(r.depth_argmax);
      r.depth_front = metric(r.depth_front);
      r.depth_median = metric(r.depth_median);
      near = 0;
      far = kUnboundedFar;
    }
    // A pixel counts where the attention looked at one place, by the estimate's own pair of depths
    // (the front with the median: quantiles, so a far tail of unbounded scenes' samples, reaching
    // 1e6, does not count; the mean with the argmax), and, with alpha masks, where the photo is opaque.
    auto agree = use_front ? (r.depth_median - r.depth_front).abs() <= opts.agreement * r.depth_front.abs()
                           : (r.depth_mean - r.depth_argmax).abs() <= opts.agreement * r.depth_mean.abs();
    const auto& depth = use_front ? r.depth_front : r.depth_mean;
    if (opts.alpha_mask) {
      const auto alpha = photo_alpha(*frames[static_cast<size_t>(i)], capture, k);
      if (alpha.defined()) agree = agree & (alpha > 0.5);
    }
    PointSet p = points_from_depth(c2w, k, depth, r.rgb, near, far, scene_box, agree);
    eyes.push_back(c2w.slice(1, 3, 4).reshape({1, 3}).to(torch::kFloat).expand({p.size(), 3}));
    sets.push_back(std::move(p));
    if (!opts.mesh_path.empty() && opts.method == MeshMethod::Tsdf)
      views.push_back({c2w, torch::where(agree, depth, torch::zeros_like(depth)), r.rgb, k});
  }
  if (progress) progress->finish();
  const double render_s = seconds_since(render_start);
  if (box_from_points) {
    // The box of the central 98% of the points on each axis, 5% wider on every side.
    const PointSet raw = concat_points(sets);
    if (raw.size() == 0) throw export_no_surface_error();
    scene_box = CropBox::around(raw.xyz, kForwardBoxShare, kForwardBoxMargin);
    for (auto& set : sets) set = crop_points(set, scene_box);
    // Each view's rows of `eyes` are its camera centre repeated: as many as its points left.
    for (size_t v = 0; v < sets.size(); ++v) eyes[v] = eyes[v].slice(0, 0, sets[v].size());
    check_tsdf_volume(opts, scene_box);
  }
  const double longest = std::max(
      {scene_box.hi[0] - scene_box.lo[0], scene_box.hi[1] - scene_box.lo[1], scene_box.hi[2] - scene_box.lo[2]});
  double voxel = longest / std::max(opts.resolution, 1);
  if (opts.resolution == 0) {
    // Auto: 1.5 pixel footprints at the median depth of the points, no finer than longest / 512.
    std::vector<torch::Tensor> depths;
    for (const auto& v : views)
      depths.push_back(v.depth.flatten().index_select(0, (v.depth.flatten() > 0).nonzero().squeeze(-1)));
    const auto d = depths.empty() ? torch::zeros({0}) : torch::cat(depths);
    const double median = d.numel() ? d.median().item<double>() : 0.0;
    voxel = std::max(longest / kMaxAutoResolution, kAutoFootprints * median / std::max(k.fx, k.fy));
  }

  nlohmann::json out;
  out["views"] = n;
  out["image"] = std::to_string(k.width) + "x" + std::to_string(k.height);
  out["render_s"] = render_s;
  out["frame"] = opts.scene_frame ? "scene" : "capture";
  out["depth"] = use_front ? "front" : "mean";
  const auto to_output = [&](torch::Tensor xyz) { return opts.scene_frame ? xyz : points_to_capture(xyz, scene); };
  const auto to_output_normals = [&](const torch::Tensor& nrm) {
    return opts.scene_frame || !nrm.defined() ? nrm : normals_to_capture(nrm, scene);
  };
  PointSet all = concat_points(sets);
  const auto eye = eyes.empty() ? torch::zeros({0, 3}) : torch::cat(eyes);
  if (!opts.preview_path.empty() && all.size() > 0) {
    // In the scene frame (+z up), before cleaning: the picture shows what the depth maps gave.
    const auto every = torch::arange(0, all.size(), std::max<int64_t>(1, all.size() / kPreviewMaxPoints));
    write_png(opts.preview_path,
              draw_preview(all.xyz.index_select(0, every), all.rgb.index_select(0, every), cams.c2w, k));
    out["preview"] = opts.preview_path;
  }

  if (!opts.points_path.empty() || opts.method == MeshMethod::Poisson) {
    const auto t = std::chrono::steady_clock::now();
    PointSet clean = clean_points(all, opts.num_points, kOutlierNeighbours, kOutlierStdRatio, eye);
    clean.xyz = to_output(clean.xyz);
    clean.normals = to_output_normals(clean.normals);
    const bool any = clean.size() > 0;
    if (opts.crop) clean = crop_points(clean, *opts.crop);
    if (!opts.points_path.empty()) {
      if (!any) throw export_no_surface_error();
      if (clean.size() == 0) throw InputError("export", "--crop", "no point of the scene lies inside the crop box");
      write_points(clean, opts.points_path);
      out["points"] = {
          {"path", opts.points_path}, {"count", clean.size()}, {"raw", all.size()}, {"seconds", seconds_since(t)}};
    }
    if (!opts.mesh_path.empty() && opts.method == MeshMethod::Poisson) {
      const auto tm = std::chrono::steady_clock::now();
      const CropBox box = opts.crop ? *opts.crop : CropBox{{-1e300, -1e300, -1e300}, {1e300, 1e300, 1e300}};
      Mesh m = poisson_mesh(clean, kPoissonDepth, kPoissonTrim, box);
      if (m.triangle_count() == 0) throw InputError("export", "--crop", "the mesh is empty inside the crop box");
      write_mesh(m, opts.mesh_path);
      out["mesh"] = {{"path", opts.mesh_path},
                     {"method", "poisson"},
                     {"vertices", m.vertex_count()},
                     {"triangles", m.triangle_count()},
                     {"seconds", seconds_since(tm)}};
    }
  }
  if (!opts.mesh_path.empty() && opts.method == MeshMethod::Tsdf) {
    const auto t = std::chrono::steady_clock::now();
    TsdfOptions to;
    to.voxel = voxel;
    to.truncation = kTruncationVoxels * voxel;
    to.crop = scene_box;
    Mesh m = fuse_tsdf(views, to);
    m.vertices = to_output(m.vertices);
    if (opts.crop) {
      // Triangles with a vertex outside the output frame's box go.
      const auto keep = opts.crop->inside(m.vertices).index({m.triangles}).all(-1).nonzero().squeeze(-1);
      m.triangles = m.triangles.index_select(0, keep);
    }
    if (m.triangle_count() == 0) throw InputError("export", "--crop", "the mesh is empty inside the crop box");
    write_mesh(m, opts.mesh_path);
    out["mesh"] = {{"path", opts.mesh_path},
                   {"method", "tsdf"},
                   {"resolution", static_cast<int>(std::lround(longest / voxel))},
                   {"voxel", voxel},
                   {"vertices", m.vertex_count()},
                   {"triangles", m.triangle_count()},
                   {"seconds", seconds_since(t)}};
  }
  out["seconds"] = seconds_since(start);
  return out;
}

void record_export(const RunFolder& run, const nlohmann::json& result) {
  nlohmann::json all = run.exports();
  nlohmann::json entry = result;
  const std::time_t now = std::time(nullptr);
  char when[32];
  std::strftime(when, sizeof when, "%Y-%m-%d %H:%M:%S UTC", std::gmtime(&now));
  entry["when"] = when;
  all.push_back(entry);
  write_file_atomic(run.exports_path(), all.dump(2) + "\n");
}

}  // namespace ablenerf
