#include "data/dataset.h"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <optional>
#include <thread>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "data/depth_file.h"
#include "data/capture.h"
#include "data/transforms_json.h"
#include "util/errors.h"
#include "util/fs.h"
#include "util/image_codec.h"
#include "util/image_io.h"
#include "util/log.h"
#include "util/progress.h"
#include "data/data_config.h"

namespace fs = std::filesystem;

namespace ablenerf {

namespace {

int64_t available_memory_bytes() {
  std::ifstream in("/proc/meminfo");
  std::string key;
  int64_t kb = 0;
  std::string unit;
  while (in >> key >> kb >> unit)
    if (key == "MemAvailable:") return kb * 1024;
  const long pages = sysconf(_SC_AVPHYS_PAGES), page = sysconf(_SC_PAGESIZE);
  return static_cast<int64_t>(pages) * page;
}

// The reduction libjpeg makes while decoding (1/2, 1/4 or 1/8, the largest that divides the
// downscale `f`): a JPEG loaded at 1/f never exists at full size. The rest of `f` is a box filter.
int jpeg_reduction(int f) {
  for (int d : {8, 4, 2})
    if (f % d == 0) return d;
  return 1;
}

// A frame's image decoded (PNG or JPEG; a JPEG reduced `reduce` times inside libjpeg) and turned
// upright when its EXIF orientation explains a size mismatch: pose tools (COLMAP, nerfstudio,
// instant-ngp) see the stored pixels, so the rotation is applied only when the capture's size says
// the poses were made on the upright image. Torch-free, so several frames decode at once without
// touching LibTorch's thread settings.
DecodedImage decode_frame(const CaptureFrame& fr, int64_t want_h, int64_t want_w, int reduce) {
  DecodedImage d = decode_image_file(fr.image, reduce);
  if (!(d.stored_height == want_h && d.stored_width == want_w) && d.exif_orientation >= 5 &&
      d.stored_height == want_w && d.stored_width == want_h) {
    apply_exif_orientation(d.image, d.exif_orientation);
    std::swap(d.stored_height, d.stored_width);
  }
  return d;
}

// "image is WxH but the capture's images are W'xH'" for a decoded image of the wrong size.
std::string size_mismatch(const char* what, const DecodedImage& decoded, int64_t want_h, int64_t want_w) {
  return std::string(what) + " is " + std::to_string(decoded.stored_width) + "x" +
         std::to_string(decoded.stored_height) + " but the capture's images are " + std::to_string(want_w) + "x" +
         std::to_string(want_h);
}

// A decoded full-size image (h', w', c) at the loaded size (h, w): box-averaged over f x f pixels
// of the stored image, after libjpeg's reduction when it made one. A reduced decode is
// ceil(size / reduced): its last row or column, from a partial block, is cropped like the
// remainder of a box filter.
torch::Tensor to_loaded_size(const torch::Tensor& im, const DecodedImage& decoded, int f, int64_t h, int64_t w) {
  return box_downscale(im, f / decoded.reduced).slice(0, 0, h).slice(1, 0, w);
}

// One frame's decoded image as (h, w, 4) float straight RGBA at the loaded size (h, w):
// box-downscaled (after libjpeg's reduction, when it made one), or cropped from the
// pre-downscaled copy.
torch::Tensor frame_rgba(const CaptureFrame& fr, const DecodedImage& decoded, int64_t want_h, int64_t want_w, int f,
                         int64_t h, int64_t w) {
  torch::Tensor raw = image_tensor(decoded.image);
  const auto size_error = [&](int64_t want_h, int64_t want_w) {
    return InputError(fr.image, fr.field,
                      size_mismatch("image", decoded, want_h, want_w) + (fr.prescaled ? " (pre-downscaled copy)" : ""));
  };
  if (fr.prescaled) {
    // images_N/ copies are W/N rounded or floored: one extra row or column is cropped.
    if (raw.size(0) < h || raw.size(1) < w || raw.size(0) > h + 1 || raw.size(1) > w + 1) throw size_error(h, w);
    raw = raw.slice(0, 0, h).slice(1, 0, w);
  } else if (decoded.stored_height != want_h || decoded.stored_width != want_w) {
    throw size_error(want_h, want_w);
  }
  torch::Tensor im = raw.to(torch::kFloat).div_(255.0f);
  if (im.size(2) == 1) im = im.expand({-1, -1, 3});
  if (im.size(2) == 3) im = torch::cat({im, torch::ones_like(im.slice(2, 0, 1))}, 2);
  // Straight RGBA, before compositing (docs/MODEL.md, section 1).
  if (!fr.prescaled) im = to_loaded_size(im, decoded, f, h, w);
  return im;
}

// A frame's mask at the loaded size (h, w) as bool "this pixel trains" (Split::mask): the first
// channel / 255 averaged over each pixel's box (after libjpeg's reduction when it made one), kept
// at >= 0.5 for masks that keep white, < 0.5 for those that mark what to leave out. The mask must
// have the capture's full size.
torch::Tensor frame_mask(const CaptureFrame& fr, const DecodedImage& decoded, int64_t full_h, int64_t full_w, int f,
                         int64_t h, int64_t w) {
  if (decoded.stored_height != full_h || decoded.stored_width != full_w)
    throw InputError(fr.mask, fr.mask_field, size_mismatch("mask", decoded, full_h, full_w));
  const torch::Tensor full = image_tensor(decoded.image).select(2, 0).to(torch::kFloat).div_(255.0f).unsqueeze(-1);
  const torch::Tensor set = to_loaded_size(full, decoded, f, h, w).squeeze(-1);
  return fr.mask_keeps_set ? set.ge(0.5f) : set.lt(0.5f);
}

// Decodes the frames of a split into tensors. The images are decoded a group at a time, one frame
// per core (the codecs are torch-free); each group then goes through LibTorch on this thread, in
// frame order, so the first bad frame in capture order is the one reported.
Split decode_split(const CaptureSplit& spec, const LoadOptions& opts, int expect_h, int expect_w,
                   const SceneFrame& scene, Progress* progress, int64_t& done, int64_t total) {
  Split s;
  s.name = spec.name;
  const int64_t n = static_cast<int64_t>(spec.frames.size());
  const int f = opts.downscale;
  const int64_t h = expect_h / f, w = expect_w / f;
  const int reduce = opts.jpeg_reduce ? jpeg_reduction(f) : 1;
  const bool use_masks = opts.masks == MaskSource::Auto;
  std::vector<torch::Tensor> keep(static_cast<size_t>(n));  // per frame, undefined = every pixel
  s.images = torch::empty({n, h, w, 3}, torch::kFloat);
  s.alpha = torch::empty({n, h, w}, torch::kFloat);
  std::vector<torch::Tensor> depths(static_cast<size_t>(n));
  const int64_t group = std::max<int64_t>(1, std::min<int64_t>(n, std::thread::hardware_concurrency()));
  for (int64_t start = 0; start < n; start += group) {
    const int64_t end = std::min(n, start + group);
    std::vector<DecodedImage> decoded(static_cast<size_t>(end - start)), masks(decoded.size());
    std::vector<std::exception_ptr> errors(decoded.size());
    const auto decode = [&](int64_t i) {
      const auto& fr = spec.frames[static_cast<size_t>(i)];
      try {
        decoded[static_cast<size_t>(i - start)] =
            decode_frame(fr, fr.prescaled ? h : expect_h, fr.prescaled ? w : expect_w, fr.prescaled ? 1 : reduce);
        if (use_masks && !fr.mask.empty()) masks[static_cast<size_t>(i - start)] = decode_image_file(fr.mask, reduce);
      } catch (...) {
        errors[static_cast<size_t>(i - start)] = std::current_exception();
      }
    };
    std::vector<std::thread> pool;
    for (int64_t i = start + 1; i < end; ++i) pool.emplace_back(decode, i);
    decode(start);
    for (auto& t : pool) t.join();
    for (int64_t i = start; i < end; ++i) {
      const auto& e = errors[static_cast<size_t>(i - start)];
      if (e) std::rethrow_exception(e);
      const auto& fr = spec.frames[static_cast<size_t>(i)];
      const torch::Tensor im = frame_rgba(fr, decoded[static_cast<size_t>(i - start)], fr.prescaled ? h : expect_h,
                                          fr.prescaled ? w : expect_w, f, h, w);
      auto rgb = im.slice(2, 0, 3), a = im.slice(2, 3, 4);
      const float bg = opts.white_background ? 1.0f : 0.0f;
      s.images[i].copy_(rgb * a + bg * (1.0f - a));
      s.alpha[i].copy_(a.squeeze(-1));
      if (opts.masks == MaskSource::Alpha) {
        keep[static_cast<size_t>(i)] = a.squeeze(-1).ge(0.5f);
      } else if (use_masks && !fr.mask.empty()) {
        keep[static_cast<size_t>(i)] =
            frame_mask(fr, masks[static_cast<size_t>(i - start)], expect_h, expect_w, f, h, w);
      }
      if (!fr.depth.empty()) {
        torch::Tensor d = read_frame_depth(fr);
        if (d.dim() != 2 || d.size(0) != expect_h || d.size(1) != expect_w)
          throw InputError(fr.depth, fr.field, "depth map size does not match the image");
        if (f > 1) d = box_downscale(d.unsqueeze(-1), f).squeeze(-1);
        depths[static_cast<size_t>(i)] = d;
      }
      ++done;
      if (progress) progress->update(done, "", done == total);
    }
  }
  std::vector<torch::Tensor> poses;
  for (const auto& fr : spec.frames) {
    poses.push_back(pose_tensor(scene.to_scene(fr.pose)));
    s.files.push_back(fr.image);
    s.cameras.push_back(fr.camera.scaled(static_cast<double>(w) / expect_w, static_cast<int>(w), static_cast<int>(h)));
  }
  s.c2w = torch::stack(poses);
  if (std::any_of(keep.begin(), keep.end(), [](const torch::Tensor& k) { return k.defined(); })) {
    for (auto& k : keep)
      if (!k.defined()) k = torch::ones({h, w}, torch::kBool);
    s.mask = torch::stack(keep);
  }
  if (!spec.frames.empty() && !spec.frames.front().depth.empty()) {
    bool all = true;
    for (const auto& d : depths) all = all && d.defined();
    // In the scene frame's units (0, a miss, stays 0).
    if (all) s.depth = torch::stack(depths).mul_(scene.scale);
  }
  return s;
}

void check_memory(const std::vector<CaptureSplit>& specs, int h, int w, const LoadOptions& opts,
                  const std::string& root) {
  double planes = 0;  // per pixel: RGB and alpha, and depth where the split has it
  for (const auto& s : specs)
    planes += static_cast<double>(s.frames.size()) * (s.frames.empty() || s.frames.front().depth.empty() ? 4 : 5);
  const int64_t hh = h / opts.downscale, ww = w / opts.downscale;
  // In double: json sizes and frame counts are untrusted and their product may not fit int64.
  const double need =
      planes * hh * ww * sizeof(float) + static_cast<double>(h) * w * 4 * 4 * 2;  // decoded + one full-res scratch
  const int64_t have = opts.memory_limit_bytes > 0 ? opts.memory_limit_bytes : available_memory_bytes();
  if (need > static_cast<double>(have))
    throw InputError(root, "images",
                     "the decoded images need " + std::to_string(static_cast<int64_t>(need / (1 << 20))) +
                         " MiB but only " + std::to_string(have / (1 << 20)) +
                         " MiB are available (try --set data.downscale=2 or fewer splits)");
}

}  // namespace

std::string small_image_note(int full_h, int full_w, int downscale) {
  const int h = full_h / downscale, w = full_w / downscale;
  if (downscale <= 1 || std::min(h, w) >= kSmallImageSide) return "";
  return "data.downscale = " + std::to_string(downscale) + " trains on " + std::to_string(w) + "x" + std::to_string(h) +
         "-pixel images (the photos are " + std::to_string(full_w) + "x" + std::to_string(full_h) +
         "); --set data.downscale=1 keeps their size";
}

const Split& Dataset::split(const std::string& name) const {
  auto it = splits.find(name);
  if (it == splits.end()) throw InputError(root, "split", "the dataset has no '" + name + "' split");
  return it->second;
}

Dataset Dataset::load(const std::string& root, const LoadOptions& opts) {
  // A capture's scene frame is fitted on all of its frames, whichever splits are decoded, so that
  // training and evaluation share it; a Blender scene's frame is fixed, so only its wanted splits
  // are read.
  const bool blender = capture_format(root) == "blender";
  return load(read_capture(root, blender ? opts.splits : std::vector<std::string>{}, opts.downscale), root, opts);
}

Dataset Dataset::load(Capture js, const std::string& root, const LoadOptions& opts) {
  const auto start = std::chrono::steady_clock::now();
  Dataset ds;
  ds.root = root;
  ds.format = js.format;
  ds.scene = fit_scene_frame(js, root, opts.scene, opts.near, opts.far, opts.bounds_from_config, opts.ndc, opts.frame);
  ds.near = ds.scene.near;
  ds.far = ds.scene.far;
  if (!opts.splits.empty()) {
    std::vector<CaptureSplit> keep;
    for (auto& sp : js.splits)
      if (std::find(opts.splits.begin(), opts.splits.end(), sp.name) != opts.splits.end())
        keep.push_back(std::move(sp));
    js.splits = std::move(keep);
  }
  if (js.splits.empty()) throw InputError(root, "split", "none of the requested splits is present");
  const int h = js.height, w = js.width;
  check_memory(js.splits, h, w, opts, root);
  if (w / opts.downscale < 1 || h / opts.downscale < 1) throw InputError(root, "downscale", "larger than the images");
  int64_t total = 0;
  for (const auto& spec : js.splits) total += static_cast<int64_t>(spec.frames.size());
  std::optional<Progress> progress;
  if (opts.progress) progress.emplace("load", total, 2.0);
  int64_t done = 0;
  for (const auto& spec : js.splits)
    ds.splits[spec.name] = decode_split(spec, opts, h, w, ds.scene, progress ? &*progress : nullptr, done, total);
  ds.intrinsics = ds.splits.begin()->second.cameras.front();
  ds.notes = js.notes;
  if (const std::string small = small_image_note(h, w, opts.downscale); !small.empty()) {
    ds.notes.push_back(small);
    log_warn("load: " + root + ": " + small);
  }
  ds.load_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (log_enabled(LogLevel::Debug)) {
    std::ostringstream line;
    line << "load: " << root << " (" << ds.format << "), " << total << " images at " << w / opts.downscale << "x"
         << h / opts.downscale << " in " << ds.load_seconds << " s";
    log_debug(line.str());
  }
  return ds;
}

torch::Tensor frame_photo_rgba(const CaptureFrame& frame, int full_h, int full_w, int downscale) {
  const int64_t h = full_h / downscale, w = full_w / downscale;
  const int64_t want_h = frame.prescaled ? h : full_h, want_w = frame.prescaled ? w : full_w;
  const int reduce = frame.prescaled ? 1 : jpeg_reduction(downscale);  // as Dataset::load's default
  return frame_rgba(frame, decode_frame(frame, want_h, want_w, reduce), want_h, want_w, downscale, h, w);
}

CameraList capture_cameras(const std::string& root, const SceneFrame& scene, int downscale) {
  return capture_cameras(read_capture(root, {}, downscale), scene, downscale);
}

CameraList capture_cameras(const Capture& js, const SceneFrame& scene, int downscale) {
  CameraList cl;
  std::vector<torch::Tensor> poses;
  for (const auto& s : js.splits)
    for (const auto& f : s.frames) poses.push_back(pose_tensor(scene.to_scene(f.pose)));
  const Intrinsics& k = js.splits.front().frames.front().camera;
  const int w = k.width / downscale, h = k.height / downscale;
  cl.intrinsics = k.scaled(static_cast<double>(w) / k.width, w, h);
  cl.c2w = torch::stack(poses);
  return cl;
}

torch::Tensor pose_tensor(const Pose34& pose) {
  auto t = torch::empty({3, 4}, torch::kFloat);
  std::memcpy(t.data_ptr<float>(), pose.data(), sizeof(float) * pose.size());
  return t;
}

torch::Tensor poses_to_scene(const torch::Tensor& c2w, const SceneFrame& scene) {
  if (scene.identity()) return c2w;
  auto in = c2w.to(torch::kFloat).contiguous();
  std::vector<torch::Tensor> out;
  for (int64_t i = 0; i < in.size(0); ++i) {
    Pose34 p;
    const auto row = in[i].slice(0, 0, 3).contiguous();
    std::memcpy(p.data(), row.data_ptr<float>(), sizeof(float) * p.size());
    out.push_back(pose_tensor(scene.to_scene(p)));
  }
  return torch::stack(out);
}

CameraList load_cameras(const std::string& path, int width, int height) {
  const CameraJson cam = read_camera_json(path, width, height);
  CameraList cl;
  cl.intrinsics = {cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height};
  std::vector<torch::Tensor> poses;
  for (const Pose34& pose : cam.poses) poses.push_back(pose_tensor(pose));
  cl.c2w = torch::stack(poses);
  return cl;
}

}  // namespace ablenerf
