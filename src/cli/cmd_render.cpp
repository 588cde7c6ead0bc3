// `ablenerf render`: renders a run's model along a camera path (orbit / spiral around the
// training cameras' mean distance and elevation) or at the poses of a cameras json, into PNG
// frames (plus depth, branch colours and raw float tensors on request) or an H.264 .mp4 through
// ffmpeg. The analyses of the paper map to ForwardOptions: --le-noise, --le-zero, --branches.
#include <ATen/CPUGeneratorImpl.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <tuple>

#include "cli/command.h"
#include "cli/common.h"
#include "data/dataset.h"
#include "eval/camera_path.h"
#include "eval/colormap.h"
#include "eval/renderer.h"
#include "eval/video.h"
#include "model/look.h"
#include "model/tonemap.h"
#include "run/run_folder.h"
#include "util/log.h"
#include "util/errors.h"
#include "util/fs.h"
#include "util/json_file.h"
#include "util/image_io.h"
#include "util/progress.h"
#include "eval/eval_config.h"
#include "data/data_config.h"

namespace fs = std::filesystem;

namespace ablenerf::cli {
namespace cmd_render {

constexpr int kDefaultFrames = 120;
constexpr double kDefaultFps = 30;

struct RenderArgs {
  std::string run, cameras, path, out, device = "auto";
  int frames = kDefaultFrames, width = 0, height = 0;
  int look = -1;  // a training photo's look (per-photo colour, appearance code); -1 = the mean
  bool raw = false, depth = false, branches = false, le_zero = false, fallback_frames = false;
  bool json = false;
  double le_noise = 0, fps = kDefaultFps;
  int64_t seed = 0, chunk = 0;
};

bool ends_with(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

// Native image size of a cameras json: its "w"/"h", else the first frame's PNG header.
// Returns {0,0} when neither is available.
std::pair<int, int> native_size(const std::string& json_path) {
  const nlohmann::json j = read_json_file(json_path);
  if (j.is_object() && j.contains("w") && j.contains("h") && j["w"].is_number() && j["h"].is_number())
    return {j["w"].get<int>(), j["h"].get<int>()};
  if (!j.is_object() || !j.contains("frames") || !j["frames"].is_array() || j["frames"].empty() ||
      !j["frames"][0].is_object() || !j["frames"][0].contains("file_path") || !j["frames"][0]["file_path"].is_string())
    return {0, 0};
  const fs::path base = fs::path(json_path).parent_path() / j["frames"][0]["file_path"].get<std::string>();
  for (const fs::path& p : {base, fs::path(base.string() + ".png")}) {
    if (fs::is_regular_file(p)) {
      const auto [h, w] = png_size(p.string());
      return {w, h};
    }
  }
  return {0, 0};
}

// Cameras json of the run's dataset (Blender training split, or a single transforms.json).
std::string dataset_cameras_json(const RunFolder& run) {
  if (run.data_dir.empty()) throw InputError(run.path("run.json"), "data", "no dataset recorded (use --cameras)");
  for (const char* name : {"transforms_train.json", "transforms.json"}) {
    const auto p = fs::path(run.data_dir) / name;
    if (fs::exists(p)) return p.string();
  }
  throw InputError(run.data_dir, "", "no transforms_train.json or transforms.json (use --cameras)");
}

// Output size: explicit --width/--height (one of them keeps the aspect ratio), else the native
// size divided by `downscale`.
std::pair<int, int> output_size(const std::string& json_path, int width, int height, int downscale) {
  if (width > 0 && height > 0) return {width, height};
  const auto [nw, nh] = native_size(json_path);
  if (nw <= 0 || nh <= 0)
    throw InputError(json_path, "w",
                     "image size unknown (no w/h and no readable first image): give --width and --height");
  if (width > 0) return {width, static_cast<int>(std::lround(static_cast<double>(width) * nh / nw))};
  if (height > 0) return {static_cast<int>(std::lround(static_cast<double>(height) * nw / nh)), height};
  return {nw / downscale, nh / downscale};
}

void save_tensor(const std::string& path, const torch::Tensor& t) {
  const std::vector<char> bytes = torch::pickle_save(t.contiguous().to(torch::kCPU, torch::kFloat));
  write_file_atomic(path, {bytes.data(), bytes.size()});
}

// Linear branch colour -> viewable sRGB in [0,1].
torch::Tensor view_linear(const torch::Tensor& x) { return linear_to_srgb(x).clamp(0.0, 1.0); }

std::string frame_name(int k) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "frame_%04d", k);
  return buf;
}

void run_render(const RenderArgs& a) {
  const torch::Device device = parse_device(a.device);
  const RunFolder run = RunFolder::open(a.run);
  const bool video = ends_with(a.out, ".mp4");
  if (video) {
    for (auto [flag, on] : std::initializer_list<std::pair<const char*, bool>>{
             {"--raw", a.raw}, {"--depth", a.depth}, {"--branches", a.branches}})
      if (on) throw InputError(flag, "", "writes extra images: give a folder as --out, not a .mp4");
  }
  if (a.le_noise < 0) throw InputError("--le-noise", "", "must be >= 0");

  // Poses and intrinsics.
  // A real capture's own cameras (any format) when no --cameras is given; a camera file's poses are
  // in the capture's coordinates and move into the run's scene frame (RUN/scene.json).
  const SceneFrame scene = run.scene();
  const bool capture = a.cameras.empty() && !run.data_dir.empty() && capture_format(run.data_dir) != "blender";
  CameraList cams;
  int w = 0, h = 0;
  if (capture) {
    cams = capture_cameras(run.data_dir, scene, run.config.get<DataConfig>().downscale);
    w = cams.intrinsics.width, h = cams.intrinsics.height;
    if (a.width > 0 || a.height > 0) {
      const double s = a.width > 0 ? static_cast<double>(a.width) / w : static_cast<double>(a.height) / h;
      w = a.width > 0 ? a.width : static_cast<int>(std::lround(w * s));
      h = a.height > 0 ? a.height : static_cast<int>(std::lround(h * s));
      cams.intrinsics = cams.intrinsics.scaled(s, w, h);
    }
  } else {
    const std::string cams_json = a.cameras.empty() ? dataset_cameras_json(run) : a.cameras;
    std::tie(w, h) =
        output_size(cams_json, a.width, a.height, a.cameras.empty() ? run.config.get<DataConfig>().downscale : 1);
    cams = load_cameras(cams_json, w, h);
    cams.c2w = poses_to_scene(cams.c2w, scene);
  }
  torch::Tensor poses = cams.c2w;
  if (!a.path.empty() && is_path_file(a.path))
    poses = read_path_file(a.path);  // recorded in the viewer, already in the scene frame
  else if (!a.path.empty())
    poses = scene.kind == SceneKind::ForwardFacing
                ? forward_facing_path(parse_path_kind(a.path), a.frames, cams.c2w)
                : camera_path(parse_path_kind(a.path), a.frames, camera_rig(cams.c2w));
  const int n = static_cast<int>(poses.size(0));
  // H.264 (yuv420p) needs even sides: an odd native size (a capture at 135x240, say) loses its
  // last column or row, principal point unchanged. An odd size asked for is refused below.
  if (video && a.width <= 0 && a.height <= 0 && (w % 2 || h % 2)) {
    log_warn("render: " + std::to_string(w) + "x" + std::to_string(h) + " cropped to " + std::to_string(w - w % 2) +
             "x" + std::to_string(h - h % 2) + " (H.264 needs even sides; --width/--height choose another size)");
    w -= w % 2, h -= h % 2;
    cams.intrinsics.width = w, cams.intrinsics.height = h;
  }

  // Output: folder of frames, or a video (or frames beside it when ffmpeg is missing and asked).
  std::string frame_dir;
  std::optional<VideoWriter> writer;
  if (video && ffmpeg_available()) {
    ensure_dir(fs::absolute(a.out).parent_path().string());
    writer.emplace(a.out, w, h, a.fps);
  } else if (video) {
    if (!a.fallback_frames)
      throw InputError("--out", "",
                       "ffmpeg not found on PATH, cannot write " + a.out +
                           " (install ffmpeg, or add --fallback-frames for PNG frames)");
    frame_dir = a.out.substr(0, a.out.size() - 4) + "_frames";
    log_warn("ffmpeg not found on PATH: writing PNG frames to " + frame_dir + " instead");
  } else {
    frame_dir = a.out;
  }
  if (!frame_dir.empty()) ensure_dir(frame_dir);

  AbleNerf model = load_run_model(run, device);
  // The capture's own cameras with the focal length the run refined, if it did (model/camera_refine.h).
  if (capture && model->camera_refine()) cams.intrinsics = model->camera_refine()->refined(cams.intrinsics);
  // --look N: the frames with training photo N's appearance code and through its colour map.
  const PhotoLook look = photo_look(*model, a.look, "--look", "");
  if ((a.le_noise > 0 || a.le_zero) && !model->has_le())
    log_warn("note: this model has no learnable embeddings (model.le_count = 0); --le-noise/--le-zero do nothing");
  torch::Generator gen = at::detail::createCPUGenerator(static_cast<uint64_t>(a.seed));
  ForwardOptions fo;
  fo.branches = a.branches;
  fo.le_noise = a.le_noise;
  fo.le_zero = a.le_zero;
  fo.generator = &gen;
  fo.appearance = look.appearance;
  const int64_t chunk = a.chunk > 0 ? a.chunk : run.config.get<EvalConfig>().chunk;
  const double near = scene.near, far = scene.far;
  // Depth colours span near..far; an unbounded scene's far (1e6) would colour everything alike, so
  // its maps span near to twice the cameras' sphere.
  const double depth_far = scene.kind == SceneKind::Unbounded ? 2.0 : far;

  const int64_t rays = static_cast<int64_t>(w) * h;
  Progress bar("render (rays)", rays * n);
  for (int k = 0; k < n; ++k) {
    const std::string note = "frame " + std::to_string(k + 1) + "/" + std::to_string(n);
    RenderResult r = render_image(model, poses[k], cams.intrinsics, near, far, chunk, fo, device,
                                  [&](int64_t done, int64_t) { bar.update(k * rays + done, note); });
    if (look.colour) r.rgb = look.colour->look(r.rgb, look.photo);
    if (writer) {
      writer->write(r.rgb);
      continue;
    }
    const std::string stem = frame_dir + "/" + frame_name(k);
    write_png(stem + ".png", r.rgb);
    if (a.raw) save_tensor(stem + ".pt", r.rgb);
    if (a.depth) {
      write_png(stem + "_depth.png", colormap(r.depth_front, near, depth_far));
      write_png(stem + "_depth_mean.png", colormap(r.depth_mean, near, depth_far));
      write_png(stem + "_depth_argmax.png", colormap(r.depth_argmax, near, depth_far));
      if (a.raw) {
        save_tensor(stem + "_depth.pt", r.depth_front);
        save_tensor(stem + "_depth_mean.pt", r.depth_mean);
        save_tensor(stem + "_depth_argmax.pt", r.depth_argmax);
      }
    }
    if (a.branches) {
      write_png(stem + "_ray.png", view_linear(r.ray_colour));
      write_png(stem + "_le.png", view_linear(r.le_colour));
      if (a.raw) {
        save_tensor(stem + "_ray.pt", r.ray_colour);
        save_tensor(stem + "_le.pt", r.le_colour);
      }
    }
  }
  if (writer) writer->close();
  bar.finish();
  const std::string where = writer ? a.out : frame_dir;
  if (a.json) {
    std::cout << nlohmann::json{{"frames", n}, {"width", w}, {"height", h}, {"out", where}}.dump() << std::endl;
    return;
  }
  std::cout << "wrote " << n << " frames (" << w << "x" << h << ") to " << where << std::endl;
}

void setup(CLI::App& app) {
  auto a = std::make_shared<RenderArgs>();
  app.add_option("--run", a->run, "Run folder written by `ablenerf train`")->required();
  auto* cams = app.add_option("--cameras", a->cameras, "Render at the poses of this Blender/transforms json");
  auto* path =
      app.add_option("--path", a->path,
                     "Camera path: FILE.json recorded in `ablenerf view`, or around the origin at the training "
                     "cameras' mean distance: "
                     "orbit (mean elevation) or spiral (elevation oscillating up to +-15 deg), over the azimuth arc "
                     "the cameras cover (out and back when they did not go all the way round)");
  cams->excludes(path);
  app.add_option("--frames", a->frames, "Frames along --path")->capture_default_str()->check(CLI::PositiveNumber);
  app.add_option("--width", a->width, "Output width (default: dataset width / data.downscale)")
      ->check(CLI::PositiveNumber);
  app.add_option("--height", a->height, "Output height (default: keeps the aspect ratio)")->check(CLI::PositiveNumber);
  app.add_flag("--raw", a->raw,
               "Also write frame_NNNN.pt: float32 (H,W,3) colours before 8-bit rounding (torch.load-able); "
               "with --depth/--branches also their tensors");
  app.add_flag("--depth", a->depth,
               "Also write depth from the fine attention: frame_NNNN_depth.png (the attention's front, where "
               "the surfaces are), _depth_mean.png (weighted mean of the interval mid-points) and "
               "_depth_argmax.png (most-attended volume), colour-mapped near..far");
  app.add_flag("--branches", a->branches,
               "Also write the fine ray-token and LE branch colours (_ray.png, _le.png): they are LINEAR "
               "values, shown through the sRGB curve and clipped for viewing (the .pt files keep them linear)");
  app.add_option("--le-noise", a->le_noise, "Add Gaussian noise of this std to the learnable embeddings");
  app.add_flag("--le-zero", a->le_zero, "Zero the learnable embeddings");
  app.add_option("--seed", a->seed, "Seed of the LE noise (same noise for every pixel and frame)")
      ->capture_default_str();
  app.add_option("--look", a->look,
                 "Render with training photo N's look: its exposure and white balance, its appearance code (a run "
                 "with train.photo_colour or train.appearance_code; default: the photos' mean look)");
  app.add_option("--fps", a->fps, "Video frame rate")->capture_default_str()->check(CLI::PositiveNumber);
  app.add_option("--chunk", a->chunk, "Rays per forward pass (default: the run's eval.chunk)")
      ->check(CLI::PositiveNumber);
  app.add_option("--device", a->device, "cpu, cuda, cuda:N or auto (cuda when available)")->capture_default_str();
  app.add_flag("--fallback-frames", a->fallback_frames,
               "With a .mp4 --out and no ffmpeg: write PNG frames to OUT_frames/ instead of failing");
  app.add_option("--out", a->out, "Output folder for PNG frames, or FILE.mp4 (needs ffmpeg)")->required();
  add_json_flag(app, a->json);
  app.callback([a] {
    if (a->cameras.empty() && a->path.empty())
      throw InputError("render", "--path", "give --path orbit|spiral|FILE.json or --cameras FILE");
    run_render(*a);
  });
}

}  // namespace cmd_render
ABLENERF_COMMAND("render", 40, "Render images or a video along a camera path", cmd_render::setup);
}  // namespace ablenerf::cli
