#include "data/colmap_process.h"

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <map>
#include <ostream>
#include <thread>

#include "data/colmap_model.h"
#include "util/errors.h"
#include "util/fs.h"
#include "util/image_codec.h"
#include "util/subprocess.h"

namespace fs = std::filesystem;

namespace ablenerf {

namespace {

const std::vector<std::string> kSfmCameraModels{"SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL",
                                                "RADIAL",         "OPENCV",  "OPENCV_FISHEYE"};

void check_options(const ProcessOptions& o) {
  if (o.images.empty() == o.video.empty()) throw InputError("process", "--images/--video", "give exactly one of them");
  if (!o.images.empty() && !fs::is_directory(o.images)) throw InputError(o.images, "--images", "not a folder");
  if (!o.video.empty() && !fs::is_regular_file(o.video)) throw InputError(o.video, "--video", "not a file");
  if (o.frames < kMinRegisteredImages)
    throw InputError("process", "--frames", "at least " + std::to_string(kMinRegisteredImages));
  if (std::find(kSfmCameraModels.begin(), kSfmCameraModels.end(), o.camera_model) == kSfmCameraModels.end())
    throw InputError("process", "--camera-model",
                     "'" + printable(o.camera_model, 40) +
                         "' is not one of SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, OPENCV_FISHEYE");
  if (o.matcher != "auto" && o.matcher != "exhaustive" && o.matcher != "sequential")
    throw InputError("process", "--matcher",
                     "'" + printable(o.matcher, 40) + "' is not auto, exhaustive or sequential");
  if (o.threads < 0) throw InputError("process", "--threads", "must be >= 0");
  if (o.out.empty()) throw InputError("process", "--out", "missing");
  if (fs::exists(o.out) && (!fs::is_directory(o.out) || !fs::is_empty(o.out)))
    throw InputError(o.out, "--out", "exists and is not an empty folder (nothing is overwritten)");
}

void require(const std::string& program, const std::string& package) {
  if (!program_available(program))
    throw EnvironmentError(program, "not found", "install it: apt-get install " + package);
}

std::string threads_arg(const ProcessOptions& o) {
  return std::to_string(o.threads > 0 ? o.threads
                                      : static_cast<int>(std::max(1u, std::thread::hardware_concurrency())));
}

// COLMAP 3.8's command-line tools create a Qt application; without a display they need this.
const std::vector<std::pair<std::string, std::string>> kColmapEnv{{"QT_QPA_PLATFORM", "offscreen"}};

// Runs one stage; a failure is the capture's (COLMAP refusing the photos), reported against the log.
void stage(const std::vector<std::string>& argv, const std::string& log, const std::string& what,
           std::ostream& progress, const std::vector<std::pair<std::string, std::string>>& env = kColmapEnv) {
  const auto t0 = std::chrono::steady_clock::now();
  progress << "process: " << what << "..." << std::flush;
  const int rc = run_logged(argv, log, env);
  progress << " " << static_cast<int>(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count())
           << " s" << std::endl;
  if (rc != 0)
    throw InputError(log, argv.size() > 1 ? argv[0] + " " + argv[1] : argv[0],
                     "failed with exit status " + std::to_string(rc) + " (its output is in this log)");
}

// Every photo readable (its header), and all of one size: one camera, and the loaders take one
// image size per capture. The odd one out is named, against the size most photos have.
void check_photos(const std::vector<std::string>& files) {
  std::map<std::pair<int, int>, int> count;
  std::vector<std::pair<int, int>> sizes;
  for (const auto& f : files) {
    sizes.push_back(image_size(f));  // InputError naming the photo when it is not a PNG or JPEG
    ++count[sizes.back()];
  }
  const auto common = std::max_element(count.begin(), count.end(), [](const auto& a, const auto& b) {
                        return a.second < b.second;
                      })->first;
  const auto text = [](const std::pair<int, int>& hw) {
    return std::to_string(hw.second) + "x" + std::to_string(hw.first);
  };
  for (size_t i = 0; i < files.size(); ++i)
    if (sizes[i] != common)
      throw InputError(files[i], "size",
                       text(sizes[i]) + " but " + std::to_string(count[common]) + " of the " +
                           std::to_string(files.size()) + " photos are " + text(common) +
                           ": a capture has one image size (rotate or resize it to match, or leave it out)");
}

int copy_photos(const std::vector<std::string>& files, const std::string& images) {
  fs::create_directories(images);
  for (const auto& f : files) fs::copy_file(f, fs::path(images) / fs::path(f).filename());
  return static_cast<int>(files.size());
}

// About `frames` evenly spaced frames of the video as JPEGs (ffmpeg's quality 2).
int extract_frames(const ProcessOptions& o, const std::string& images, const std::string& log, std::ostream& progress) {
  require(o.ffmpeg, "ffmpeg");
  require(o.ffprobe, "ffmpeg");
  int status = 0;
  const std::string counted = run_captured({o.ffprobe, "-v", "error", "-select_streams", "v:0", "-count_packets",
                                            "-show_entries", "stream=nb_read_packets", "-of", "csv=p=0", o.video},
                                           log, &status);
  long total = 0;
  try {
    total = std::stol(counted);
  } catch (const std::exception&) {
    total = 0;
  }
  if (status != 0 || total <= 0) throw InputError(o.video, "--video", "ffprobe finds no video frames in it");
  const long every = std::max(1L, total / o.frames);
  fs::create_directories(images);
  stage({o.ffmpeg, "-hide_banner", "-loglevel", "error", "-i", o.video, "-vf",
         "select=not(mod(n\\," + std::to_string(every) + "))", "-vsync", "vfr", "-q:v", "2",
         (fs::path(images) / "frame_%05d.jpg").string()},
        log, "extracting every " + std::to_string(every) + " of " + std::to_string(total) + " frames", progress, {});
  const int n = static_cast<int>(image_files(images).size());
  if (n == 0) throw InputError(o.video, "--video", "ffmpeg wrote no frames (see " + log + ")");
  return n;
}

}  // namespace

std::vector<std::vector<std::string>> colmap_commands(const ProcessOptions& o, const std::string& out, int n_images) {
  const std::string db = (fs::path(out) / "database.db").string(), images = (fs::path(out) / "images").string();
  const std::string threads = threads_arg(o);
  // A video's frames are in order: each needs matching with its neighbours only.
  const bool exhaustive =
      o.matcher == "exhaustive" || (o.matcher == "auto" && o.video.empty() && n_images <= kExhaustiveMaxImages);
  return {
      {o.colmap, "feature_extractor", "--database_path", db, "--image_path", images, "--ImageReader.single_camera",
       o.single_camera ? "1" : "0", "--ImageReader.camera_model", o.camera_model, "--SiftExtraction.use_gpu", "0",
       "--SiftExtraction.num_threads", threads},
      {o.colmap, exhaustive ? "exhaustive_matcher" : "sequential_matcher", "--database_path", db,
       "--SiftMatching.use_gpu", "0", "--SiftMatching.num_threads", threads},
      {o.colmap, "mapper", "--database_path", db, "--image_path", images, "--output_path",
       (fs::path(out) / "sparse").string(), "--Mapper.num_threads", threads},
  };
}

ProcessResult process_capture(const ProcessOptions& o, std::ostream& progress) {
  check_options(o);
  require(o.colmap, "colmap");
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<std::string> photos;
  if (!o.images.empty()) {
    std::vector<std::string> others;
    photos = image_files(o.images, &others);
    const std::string convert =
        others.empty() ? ""
                       : std::to_string(others.size()) + (others.size() > 1 ? " other images (" : " other image (") +
                             printable(others.front(), 60) + (others.size() > 1 ? ", ...) are" : ") is") +
                             " not read: convert to JPEG (HEIC: heif-convert from Debian's libheif-examples; "
                             "TIFF, WebP, RAW: ffmpeg or your photo tool)";
    if (photos.empty())
      throw InputError(o.images, "--images",
                       "no JPEG or PNG photos in this folder" + (convert.empty() ? "" : "; " + convert));
    if (!convert.empty()) progress << "process: note: " << convert << std::endl;
    check_photos(photos);
  }
  fs::create_directories(o.out);
  const std::string log = (fs::path(o.out) / "colmap.log").string();
  const std::string images = (fs::path(o.out) / "images").string();
  progress << "process: COLMAP's own progress goes to " << log << " (50 phone photos: about 7 minutes on 2 cores)"
           << std::endl;
  ProcessResult r;
  r.images = o.video.empty() ? copy_photos(photos, images) : extract_frames(o, images, log, progress);
  fs::create_directories(fs::path(o.out) / "sparse");
  const auto cmds = colmap_commands(o, o.out, r.images);
  r.matcher = cmds[1][1];
  stage(cmds[0], log, "COLMAP features of " + std::to_string(r.images) + " images", progress);
  stage(cmds[1], log, "COLMAP " + r.matcher, progress);
  stage(cmds[2], log, "COLMAP mapper", progress);

  // The mapper writes one model per connected group of photos (sparse/0, sparse/1, ...): keep the
  // one with the most registered images as sparse/0.
  ColmapModel best;  // best.dir: the model's folder
  for (const auto& e : fs::directory_iterator(fs::path(o.out) / "sparse")) {
    if (!e.is_directory()) continue;
    try {
      ColmapModel m = read_colmap_model(e.path().string());
      if (m.images.size() > best.images.size()) best = std::move(m);
    } catch (const InputError&) {
      // not a model
    }
  }
  r.registered = static_cast<int>(best.images.size());
  if (r.registered < kMinRegisteredImages)
    throw InputError(log, "registered images",
                     "COLMAP placed " + std::to_string(r.registered) + " of " + std::to_string(r.images) +
                         " images: too few; take more photos with more overlap (each part of the scene in several "
                         "photos, moving between shots rather than turning on the spot)");
  if (r.registered < r.images)
    progress << "process: note: COLMAP placed " << r.registered << " of " << r.images
             << " images; the others are not in the capture (photos that overlap more bring them in)" << std::endl;
  const fs::path zero = fs::path(o.out) / "sparse" / "0";
  if (fs::path(best.dir) != zero) {
    const fs::path aside = fs::path(o.out) / "sparse" / "0_smaller";
    if (fs::exists(zero)) fs::rename(zero, aside);
    fs::rename(best.dir, zero);
  }
  r.points = best.points.size();
  const ColmapCamera& cam = best.cameras.front();
  r.camera = cam.model + " " + std::to_string(cam.width) + "x" + std::to_string(cam.height);
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return r;
}

}  // namespace ablenerf
