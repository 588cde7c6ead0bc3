// libFuzzer target: the COLMAP model reader (data/colmap_model, torch-free) on arbitrary bytes.
// The input is cut into three parts at the first two occurrences of the separator "\xffSEP"
// (cameras, images, points3D; a missing separator leaves the later parts absent). Each part goes
// through its binary and its text parser, then the parts are written as the files of a model
// folder, once as .bin and once as .txt, and read back with read_colmap_model (with points3D
// left out when the input has no second separator, the "no points" case).
// Every call must either return or throw InputError. Findings: any other exception, a crash, a
// sanitizer report (an allocation over -rss_limit_mb included: counts must be checked against the
// bytes left before anything is reserved), or a result that breaks the reader's promises (see
// check_* below).
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <set>
#include <string>
#include <vector>

#include "data/colmap_model.h"
#include "fuzz_common.h"
#include "util/errors.h"

namespace {

const std::string kSeparator = "\xffSEP";

[[noreturn]] void finding(const char* what) {
  std::fprintf(stderr, "fuzz_colmap: %s\n", what);
  std::abort();
}

void check_cameras(const std::vector<ablenerf::ColmapCamera>& cameras) {
  std::set<uint32_t> ids;
  for (const auto& c : cameras) {
    if (!ids.insert(c.id).second) finding("duplicate camera id accepted");
    if (c.model_id < 0 || c.model != ablenerf::colmap_model_name(c.model_id)) finding("model id and name disagree");
    if (static_cast<int>(c.params.size()) != ablenerf::colmap_model_params(c.model))
      finding("parameter count does not match the model");
    if (c.width < 1 || c.height < 1 || c.width > (1u << 20) || c.height > (1u << 20))
      finding("image size out of range");
    for (double p : c.params)
      if (!std::isfinite(p)) finding("non-finite camera parameter");
  }
}

void check_images(const std::vector<ablenerf::ColmapImage>& images) {
  std::set<uint32_t> ids;
  for (const auto& im : images) {
    if (!ids.insert(im.id).second) finding("duplicate image id accepted");
    double n = 0;
    for (double q : im.qvec) n += q * q;
    if (!(std::abs(n - 1) < 1e-9)) finding("qvec not normalised");
    for (double t : im.tvec)
      if (!std::isfinite(t)) finding("non-finite tvec");
    if (im.name.empty() || im.name.find('\0') != std::string::npos) finding("empty name or a name with NUL");
    for (uint64_t id : im.point3d_ids)
      if (id == UINT64_MAX) finding("an observation without a point kept in point3d_ids");
  }
}

void check_points(const std::vector<ablenerf::ColmapPoint>& points) {
  for (const auto& p : points)
    for (double x : p.xyz)
      if (!std::isfinite(x)) finding("non-finite point");
}

void check_model(const ablenerf::ColmapModel& m) {
  check_cameras(m.cameras);
  check_images(m.images);
  check_points(m.points);
  std::set<uint32_t> cams;
  for (const auto& c : m.cameras) cams.insert(c.id);
  for (const auto& im : m.images)
    if (!cams.count(im.camera_id)) finding("an image whose camera is not in the model");
}

// Runs `f`; an InputError is the expected refusal, anything else escapes to libFuzzer (a finding).
template <class F>
void refused_or_ok(F&& f) {
  try {
    f();
  } catch (const ablenerf::InputError&) {
  }
}

void write_model(const std::string& dir, const std::string& ext, const std::vector<std::string>& parts) {
  static const char* const kNames[] = {"cameras", "images", "points3D"};
  std::filesystem::create_directories(dir);
  for (size_t k = 0; k < 3; ++k) {
    const std::string path = dir + "/" + kNames[k] + "." + ext;
    if (k < parts.size()) {
      ablenerf::fuzz::write_bytes(path, reinterpret_cast<const uint8_t*>(parts[k].data()), parts[k].size());
    } else {
      std::error_code ec;
      std::filesystem::remove(path, ec);
    }
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string in(reinterpret_cast<const char*>(data), size);
  std::vector<std::string> parts;
  size_t start = 0;
  while (parts.size() < 2) {
    const size_t at = in.find(kSeparator, start);
    if (at == std::string::npos) break;
    parts.push_back(in.substr(start, at - start));
    start = at + kSeparator.size();
  }
  parts.push_back(in.substr(start));
  const std::string none;
  const std::string& cameras = parts[0];
  const std::string& images = parts.size() > 1 ? parts[1] : none;
  const std::string& points = parts.size() > 2 ? parts[2] : none;

  refused_or_ok([&] { check_cameras(ablenerf::parse_cameras_bin(cameras, "cameras.bin")); });
  refused_or_ok([&] { check_images(ablenerf::parse_images_bin(images, "images.bin")); });
  refused_or_ok([&] { check_points(ablenerf::parse_points3d_bin(points, "points3D.bin")); });
  refused_or_ok([&] { check_cameras(ablenerf::parse_cameras_txt(cameras, "cameras.txt")); });
  refused_or_ok([&] { check_images(ablenerf::parse_images_txt(images, "images.txt")); });
  refused_or_ok([&] { check_points(ablenerf::parse_points3d_txt(points, "points3D.txt")); });

  const std::string bin_dir = ablenerf::fuzz::scratch_dir() + "/bin";
  const std::string txt_dir = ablenerf::fuzz::scratch_dir() + "/txt";
  write_model(bin_dir, "bin", parts);
  write_model(txt_dir, "txt", parts);
  refused_or_ok([&] { check_model(ablenerf::read_colmap_model(bin_dir)); });
  refused_or_ok([&] {
    const ablenerf::ColmapModel m = ablenerf::read_colmap_model(txt_dir);
    if (m.encoding != "txt") finding("txt folder read as bin");
    check_model(m);
  });
  return 0;
}
