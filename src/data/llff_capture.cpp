// An LLFF capture: poses_bounds.npy (N x 17: a 3x5 matrix per image, the pose in LLFF's
// [down, right, backwards] axes plus a column [height, width, focal], then the near and far depth of
// the scene in that image) and the images of ROOT/images/ in name order. Torch-free.
//
// LLFF's own release (nerf_llff_data) also ships minified copies in images_N/ named image000.png,
// image001.png, ... while images/ keeps the camera's names: NeRF's load_llff pairs the rows with the
// copies in sorted order, and so does this reader when no copy shares a photo's stem. A capture with
// only images_N/ (no full-size photos) loads at data.downscale = N, the camera from the npy's size.
#include <algorithm>
#include <cmath>
#include <filesystem>

#include "data/capture_formats.h"
#include "data/npy.h"
#include "util/errors.h"
#include "util/image_codec.h"

namespace fs = std::filesystem;

namespace ablenerf {

namespace {
constexpr int64_t kLlffColumns = 17;
}  // namespace

bool is_llff_capture(const std::string& root) { return fs::exists(fs::path(root) / "poses_bounds.npy"); }

void read_llff_capture(const std::string& root, const std::vector<std::string>& splits, int downscale, Capture& out) {
  const std::string file = (fs::path(root) / "poses_bounds.npy").string();
  const NpyArray a = read_npy(file);
  if (a.shape.size() != 2 || a.shape[1] != kLlffColumns || a.shape[0] < 1)
    throw InputError(file, "shape", "expected (N, 17) poses and bounds");
  const int64_t n = a.shape[0];
  const std::string copies_name = "images_" + std::to_string(downscale);
  const fs::path dir = fs::path(root) / "images", copies = fs::path(root) / copies_name;
  const bool have_photos = fs::is_directory(dir);
  const bool have_copies = downscale > 1 && fs::is_directory(copies);
  const bool copies_only = !have_photos && have_copies;
  if (!have_photos && !copies_only)
    throw InputError(root, "images",
                     "folder not found (LLFF keeps its images in images/, or only their copies in images_N/ "
                     "for data.downscale = N)");
  const auto file_names = [](const fs::path& folder) {
    std::vector<std::string> out;
    for (const auto& f : image_files(folder.string())) out.push_back(fs::path(f).filename().string());
    return out;
  };
  const fs::path listed = copies_only ? copies : dir;
  const std::vector<std::string> names = file_names(listed);
  if (static_cast<int64_t>(names.size()) != n)
    throw InputError(
        file, "shape",
        std::to_string(n) + " poses but " + std::to_string(names.size()) + " images in " + listed.string());
  // The copies paired by sorted order (LLFF's release naming) when none shares the first photo's stem.
  std::vector<std::string> copies_by_order;
  if (have_copies && !copies_only) {
    std::vector<std::string> c = file_names(copies);
    const std::string stem0 = fs::path(names.front()).stem().string();
    const bool shared =
        std::any_of(c.begin(), c.end(), [&](const std::string& x) { return fs::path(x).stem() == stem0; });
    if (!shared && static_cast<int64_t>(c.size()) == n) copies_by_order = std::move(c);
  }
  out.format = "llff";
  std::vector<CaptureFrame> frames;
  for (int64_t i = 0; i < n; ++i) {
    const double* r = a.data.data() + i * kLlffColumns;
    const std::string where = "row " + std::to_string(i) + " (" + names[static_cast<size_t>(i)] + ")";
    for (int64_t c = 0; c < kLlffColumns; ++c)
      if (!std::isfinite(r[c])) throw InputError(file, where, "non-finite value");
    // r is the row-major 3x5 matrix, then near, far.
    const auto at = [&](int row, int col) { return r[row * 5 + col]; };
    const double h = at(0, 4), w = at(1, 4), f = at(2, 4);
    if (!(h >= 1 && w >= 1 && h <= (1 << 20) && w <= (1 << 20) && f > 0))
      throw InputError(file, where, "height, width and focal (column 5) must be positive");
    double c2w[3][4];
    for (int row = 0; row < 3; ++row) {
      c2w[row][0] = at(row, 1);   // right
      c2w[row][1] = -at(row, 0);  // up = -down
      c2w[row][2] = at(row, 2);   // backwards
      c2w[row][3] = at(row, 3);
    }
    CaptureFrame fr;
    fr.field = where;
    fr.pose = checked_pose(c2w, file, where);
    const std::string name = names[static_cast<size_t>(i)];
    if (copies_only) {
      // No full-size photo: the camera at the npy's size, the copy decoded as it is (the dataset
      // checks that it is that size / N).
      fr.image = resolve_in_root(root, copies_name + "/" + name, file, where);
      fr.prescaled = true;
      fr.camera.width = static_cast<int>(std::lround(w));
      fr.camera.height = static_cast<int>(std::lround(h));
      fr.camera.fx = fr.camera.fy = f;
      fr.camera.cx = 0.5 * w;
      fr.camera.cy = 0.5 * h;
    } else {
      fr.image = resolve_in_root(root, "images/" + name, file, where);
      // The npy's size is the one the poses were computed at; the stored images may be another
      // (LLFF ships full-size photos): the camera follows the image.
      const auto hw = image_size(fr.image);
      const double s = static_cast<double>(hw.second) / w;
      fr.camera.width = hw.second;
      fr.camera.height = hw.first;
      fr.camera.fx = fr.camera.fy = f * s;
      fr.camera.cx = 0.5 * hw.second;
      fr.camera.cy = 0.5 * hw.first;
      if (std::abs(h * s - hw.first) > 1.0)
        throw InputError(fr.image, where, "aspect ratio differs from the npy's height and width");
    }
    if (frames.empty()) {
      out.width = fr.camera.width, out.height = fr.camera.height;
    } else if (fr.camera.width != out.width || fr.camera.height != out.height) {
      throw InputError(fr.image, where, "image size differs from the first image's");
    }
    const double near = r[15], far = r[16];
    if (!(near > 0 && far > near)) throw InputError(file, where + ": bounds", "need 0 < near < far");
    if (!copies_only) {
      fr.mask = mask_in_folder(root, fr.image, where);
      fr.mask_field = "masks/";
      const std::string small =
          copies_by_order.empty()
              ? resolve_downscaled(root, fr.image, downscale)
              : resolve_in_root(root, copies_name + "/" + copies_by_order[static_cast<size_t>(i)], file, where);
      if (!small.empty()) fr.image = small, fr.prescaled = true;
    }
    out.bounds.push_back({near, far});
    frames.push_back(std::move(fr));
  }
  out.notes.push_back("LLFF poses_bounds.npy: " + std::to_string(n) + " images");
  split_every_eighth(std::move(frames), splits, file, FrameOrder::ByImageName, out);
}

}  // namespace ablenerf
