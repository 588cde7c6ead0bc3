#include "data/dataset.h"

#include <unistd.h>

#include <cstring>
#include <filesystem>
#include <fstream>

#include "data/transforms_json.h"
#include "util/errors.h"
#include "util/fs.h"
#include "util/image_io.h"

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

// A pose as a (3,4) float tensor.
torch::Tensor pose_tensor(const Pose34& pose) {
  auto t = torch::empty({3, 4}, torch::kFloat);
  std::memcpy(t.data_ptr<float>(), pose.data(), sizeof(float) * pose.size());
  return t;
}

// Decodes the frames of a split into tensors.
Split decode_split(const SplitJson& spec, const LoadOptions& opts, int expect_h, int expect_w) {
  Split s;
  s.name = spec.name;
  const int64_t n = static_cast<int64_t>(spec.frames.size());
  const int f = opts.downscale;
  const int64_t h = expect_h / f, w = expect_w / f;
  s.images = torch::empty({n, h, w, 3}, torch::kFloat);
  s.alpha = torch::empty({n, h, w}, torch::kFloat);
  std::vector<torch::Tensor> poses, depths;
  for (int64_t i = 0; i < n; ++i) {
    const auto& fr = spec.frames[static_cast<size_t>(i)];
    torch::Tensor raw = read_png(fr.image);
    if (raw.size(0) != expect_h || raw.size(1) != expect_w)
      throw InputError(fr.image, fr.field,
                       "image is " + std::to_string(raw.size(1)) + "x" + std::to_string(raw.size(0)) +
                           " but the split's images are " + std::to_string(expect_w) + "x" +
                           std::to_string(expect_h));
    torch::Tensor im = raw.to(torch::kFloat).div_(255.0f);
    if (im.size(2) == 1) im = im.expand({-1, -1, 3});
    if (im.size(2) == 3) im = torch::cat({im, torch::ones_like(im.slice(2, 0, 1))}, 2);
    im = box_downscale(im, f);  // straight RGBA, before compositing (spec 1.1)
    auto rgb = im.slice(2, 0, 3), a = im.slice(2, 3, 4);
    const float bg = opts.white_background ? 1.0f : 0.0f;
    s.images[i].copy_(rgb * a + bg * (1.0f - a));
    s.alpha[i].copy_(a.squeeze(-1));
    poses.push_back(pose_tensor(fr.pose));
    s.files.push_back(fr.image);
    if (!fr.depth.empty()) {
      torch::Tensor d;
      try {
        const std::string bytes = read_file(fr.depth);
        d = torch::pickle_load(std::vector<char>(bytes.begin(), bytes.end())).toTensor().to(torch::kFloat);
      } catch (const InputError&) {
        throw;
      } catch (const std::exception&) {
        throw InputError(fr.depth, fr.field, "cannot read depth tensor");
      }
      if (d.dim() != 2 || d.size(0) != expect_h || d.size(1) != expect_w)
        throw InputError(fr.depth, fr.field, "depth map size does not match the image");
      if (f > 1) d = box_downscale(d.unsqueeze(-1), f).squeeze(-1);
      depths.push_back(d);
    }
  }
  s.c2w = torch::stack(poses);
  if (!depths.empty() && depths.size() == static_cast<size_t>(n)) s.depth = torch::stack(depths);
  return s;
}

void check_memory(const std::vector<SplitJson>& specs, int h, int w, const LoadOptions& opts,
                  const std::string& root) {
  int64_t frames = 0;
  for (const auto& s : specs) frames += static_cast<int64_t>(s.frames.size());
  const int64_t hh = h / opts.downscale, ww = w / opts.downscale;
  // In double: json sizes and frame counts are untrusted and their product may not fit int64.
  const double need = static_cast<double>(frames) * hh * ww * 4 * sizeof(float) +
                      static_cast<double>(h) * w * 4 * 4 * 2;  // decoded + one full-res scratch
  const int64_t have = opts.memory_limit_bytes > 0 ? opts.memory_limit_bytes : available_memory_bytes();
  if (need > static_cast<double>(have))
    throw InputError(root, "images",
                     "the decoded images need " + std::to_string(static_cast<int64_t>(need / (1 << 20))) +
                         " MiB but only " +
                         std::to_string(have / (1 << 20)) +
                         " MiB are available (try --set data.downscale=2 or fewer splits)");
}

}  // namespace

const Split& Dataset::split(const std::string& name) const {
  auto it = splits.find(name);
  if (it == splits.end()) throw InputError(root, "split", "the dataset has no '" + name + "' split");
  return it->second;
}

std::vector<std::string> available_splits(const std::string& root) {
  std::vector<std::string> out;
  for (const char* s : {"train", "val", "test"})
    if (fs::exists(fs::path(root) / ("transforms_" + std::string(s) + ".json"))) out.push_back(s);
  if (out.empty() && fs::exists(fs::path(root) / "transforms.json")) out = {"train", "test"};
  return out;
}

Dataset Dataset::load(const std::string& root, const LoadOptions& opts) {
  const DatasetJson js = read_dataset_json(root, opts.splits, opts.downscale);
  Dataset ds;
  ds.root = root;
  ds.format = js.format;
  ds.near = opts.near;
  ds.far = opts.far;
  const int h = js.height, w = js.width;
  check_memory(js.splits, h, w, opts, root);
  ds.intrinsics.width = w / opts.downscale;
  ds.intrinsics.height = h / opts.downscale;
  ds.intrinsics.fx = js.fx;
  ds.intrinsics.fy = js.fy;
  ds.intrinsics.cx = js.cx >= 0 ? js.cx : 0.5 * ds.intrinsics.width;
  ds.intrinsics.cy = js.cy >= 0 ? js.cy : 0.5 * ds.intrinsics.height;
  if (ds.intrinsics.width < 1 || ds.intrinsics.height < 1)
    throw InputError(root, "downscale", "larger than the images");
  for (const auto& spec : js.splits) ds.splits[spec.name] = decode_split(spec, opts, h, w);
  return ds;
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
