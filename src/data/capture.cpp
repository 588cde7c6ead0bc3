#include "data/capture.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

#include "data/capture_formats.h"
#include "util/errors.h"

namespace fs = std::filesystem;

namespace ablenerf {

namespace {
// Tolerance of the rigidity check: poses are written with ~6-7 significant digits.
constexpr double kRigidTolerance = 1e-3;  // max |R^T R - I|
}  // namespace

const std::vector<CaptureFormat>& capture_formats() {
  static const std::vector<CaptureFormat> formats{
      {"blender", is_blender_capture, read_blender_capture},
      {"transforms", is_transforms_capture, read_transforms_capture},
      {"colmap", is_colmap_capture, read_colmap_capture},
      {"llff", is_llff_capture, read_llff_capture},
  };
  return formats;
}

namespace {
// The first row of the registry whose detect claims `root`, or nullptr.
const CaptureFormat* detected_format(const std::string& root) {
  for (const auto& f : capture_formats())
    if (f.detect(root)) return &f;
  return nullptr;
}
}  // namespace

std::string capture_format(const std::string& root) {
  const CaptureFormat* f = detected_format(root);
  return f ? f->name : "";
}

std::vector<std::string> Capture::split_names() const {
  std::vector<std::string> out;
  for (const auto& s : splits) out.push_back(s.name);
  return out;
}

Capture read_capture(const std::string& root, const std::vector<std::string>& splits, int downscale) {
  if (!fs::is_directory(root)) throw InputError(root, "", "dataset folder not found");
  if (downscale < 1) throw InputError(root, "downscale", "must be >= 1");
  const CaptureFormat* format = detected_format(root);
  if (!format)
    throw InputError(root, "transforms_train.json",
                     "no capture found: expected transforms_{train,val,test}.json (Blender), transforms.json "
                     "(instant-ngp / nerfstudio), sparse/0/cameras.{bin,txt} (COLMAP) or poses_bounds.npy (LLFF)");
  Capture out;
  format->read(root, splits, downscale, out);
  for (const auto& s : out.splits)
    for (const auto& f : s.frames) {
      check_focal(f.camera.fx, s.file, f.field + " (focal)");
      check_focal(f.camera.fy, s.file, f.field + " (focal)");
    }
  return out;
}

bool split_wanted(const std::vector<std::string>& splits, const std::string& split) {
  return splits.empty() || std::find(splits.begin(), splits.end(), split) != splits.end();
}

std::string resolve_in_root(const std::string& root, const std::string& rel, const std::string& file,
                            const std::string& field, bool add_png) {
  if (rel.empty()) throw InputError(file, field, "empty path");
  fs::path p = fs::path(root) / rel;
  if (add_png && !p.has_extension()) p += ".png";
  if (add_png && p.extension() != ".png" && !fs::exists(p)) p += ".png";
  std::error_code ec;
  const fs::path canon_root = fs::weakly_canonical(fs::path(root), ec);
  const fs::path canon = fs::weakly_canonical(p, ec);
  const std::string r = canon_root.string(), c = canon.string();
  if (c.compare(0, r.size(), r) != 0 || (c.size() > r.size() && c[r.size()] != '/'))
    throw InputError(file, field, "path '" + rel + "' points outside the dataset folder");
  if (!fs::is_regular_file(canon)) throw InputError(file, field, "image not found: " + p.string());
  return canon.string();
}

namespace {
// The image in `dir` named `stem` with any image extension, `preferred` (e.g. the photo's own) first;
// empty when there is none. Serves the images_N/ copies and the masks/ folder alike.
fs::path same_stem_image(const fs::path& dir, const std::string& stem, const std::string& preferred = "") {
  std::vector<std::string> exts{".png", ".jpg", ".jpeg", ".PNG", ".JPG", ".JPEG", ".Png", ".Jpg"};
  if (!preferred.empty()) exts.insert(exts.begin(), preferred);
  for (const std::string& ext : exts) {
    const fs::path cand = dir / (stem + ext);
    if (fs::is_regular_file(cand)) return cand;
  }
  return {};
}
}  // namespace

std::string resolve_downscaled(const std::string& root, const std::string& image, int downscale) {
  if (downscale <= 1) return "";
  std::error_code ec;
  const fs::path canon_root = fs::weakly_canonical(fs::path(root), ec);
  const fs::path rel = fs::path(image).lexically_relative(canon_root);
  if (rel.empty() || *rel.begin() == "..") return "";
  auto it = rel.begin();
  const std::string top = it->string();
  if (top != "images") return "";
  fs::path rest;
  for (++it; it != rel.end(); ++it) rest /= *it;
  const fs::path dir = canon_root / ("images_" + std::to_string(downscale)) / rest.parent_path();
  if (!fs::is_directory(dir)) return "";
  const fs::path cand = same_stem_image(dir, rest.stem().string(), rest.extension().string());
  if (cand.empty()) return "";
  return resolve_in_root(root, cand.lexically_relative(canon_root).string(), image,
                         "images_" + std::to_string(downscale));
}

std::string blender_depth_file(const std::string& image) {
  const fs::path p(image);
  const fs::path depth = p.parent_path() / (p.stem().string() + "_depth_0001.png");
  return fs::is_regular_file(depth) ? depth.string() : std::string();
}

std::string mask_in_folder(const std::string& root, const std::string& image, const std::string& field) {
  std::error_code ec;
  const fs::path canon_root = fs::weakly_canonical(fs::path(root), ec);
  const fs::path masks = canon_root / "masks";
  if (!fs::is_directory(masks)) return "";
  const fs::path rel = fs::path(image).lexically_relative(canon_root / "images");
  if (rel.empty() || *rel.begin() == "..") return "";
  // The photo's own stem, or the stem and "_mask" (NeRD's and several photogrammetry tools' naming).
  fs::path cand = same_stem_image(masks / rel.parent_path(), rel.stem().string());
  if (cand.empty()) cand = same_stem_image(masks / rel.parent_path(), rel.stem().string() + "_mask");
  if (!cand.empty()) return fs::weakly_canonical(cand, ec).string();
  throw InputError(masks.string(), field,
                   "no mask for images/" + rel.string() + " (masks/" + (rel.parent_path() / rel.stem()).string() +
                       ".png or .jpg, or the same with _mask after the name)");
}

void split_every_eighth(std::vector<CaptureFrame> all, const std::vector<std::string>& splits, const std::string& file,
                        FrameOrder order, Capture& out) {
  if (order == FrameOrder::ByImageName)
    std::stable_sort(all.begin(), all.end(),
                     [](const CaptureFrame& a, const CaptureFrame& b) { return a.image < b.image; });
  CaptureSplit train{"train", file, {}}, test{"test", file, {}};
  for (size_t i = 0; i < all.size(); ++i)
    (i % kTestEvery == 0 && all.size() > 1 ? test : train).frames.push_back(all[i]);
  if (split_wanted(splits, "train") && !train.frames.empty()) out.splits.push_back(std::move(train));
  if (split_wanted(splits, "test") && !test.frames.empty()) out.splits.push_back(std::move(test));
  out.notes.push_back(order == FrameOrder::ByImageName ? "split: every 8th image (sorted by name) held out for test"
                                                       : "split: every 8th frame held out for test");
}

Pose34 checked_pose(const double (&a)[3][4], const std::string& file, const std::string& field) {
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c)
      if (!std::isfinite(a[r][c])) throw InputError(file, field, "non-finite value");
  // Rigid: columns of R orthonormal, det +1.
  double worst = 0;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      double dot = 0;
      for (int k = 0; k < 3; ++k) dot += a[k][i] * a[k][j];
      worst = std::max(worst, std::abs(dot - (i == j ? 1.0 : 0.0)));
    }
  const double det = a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1]) -
                     a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0]) +
                     a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
  if (worst > kRigidTolerance || det < 0)
    throw InputError(file, field,
                     "not a rigid transform (rotation part not orthonormal with det +1: max |R^T R - I| = " +
                         std::to_string(worst) + ", det = " + std::to_string(det) + ")");
  Pose34 pose;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) pose[static_cast<size_t>(r * 4 + c)] = static_cast<float>(a[r][c]);
  return pose;
}

// A focal length in pixels: positive and finite, since every ray direction divides by it.
void check_focal(double f, const std::string& file, const std::string& field) {
  if (!(f > 0 && std::isfinite(f))) throw InputError(file, field, "must be positive");
}

}  // namespace ablenerf
