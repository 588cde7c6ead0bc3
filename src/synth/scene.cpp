#include "synth/scene.h"

#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <sstream>
#include <string>
#include <atomic>
#include <exception>
#include <mutex>
#include <nlohmann/json.hpp>
#include <thread>

#include "synth/room.h"
#include "synth/room_camera.h"
#include "util/errors.h"
#include "util/fs.h"
#include "util/image_io.h"

namespace ablenerf::synth {

namespace {

using nlohmann::json;

// The depth visualisation maps the scene's depth range (demo: camera distance +- scene bound;
// room: kRoomDepthNear to kRoomDepthFar, about the farthest corner's depth from the cameras) to
// grey levels in [kDepthGreyFar, 1] (near = bright); misses stay black.
constexpr double kDepthGreyFar = 0.15;
constexpr double kRoomDepthNear = 0.5, kRoomDepthFar = 4.5;

json vec_json(const Vec3& v) { return json::array({v.x, v.y, v.z}); }

json pose_json(const Camera& cam) {
  json m = json::array();
  for (int r = 0; r < 3; ++r) m.push_back(json::array({cam.c2w[r][0], cam.c2w[r][1], cam.c2w[r][2], cam.c2w[r][3]}));
  m.push_back(json::array({0.0, 0.0, 0.0, 1.0}));
  return m;
}

json box_json(const Vec3& lo, const Vec3& hi) { return json{{"min", vec_json(lo)}, {"max", vec_json(hi)}}; }

json transforms_json(const std::vector<Camera>& cams, const std::string& split, bool with_depth, bool with_masks) {
  json frames = json::array();
  for (size_t k = 0; k < cams.size(); ++k) {
    json f;
    f["file_path"] = "./" + split + "/r_" + std::to_string(k);
    f["transform_matrix"] = pose_json(cams[k]);
    if (with_depth) f["depth_file_path"] = "./" + split + "/r_" + std::to_string(k) + "_depth.pt";
    if (with_masks) f["mask_path"] = "./" + split + "/r_" + std::to_string(k) + "_mask.png";
    frames.push_back(f);
  }
  return json{{"camera_angle_x", kCameraAngleX}, {"frames", frames}};
}

// nerfstudio's layout: one transforms.json, every frame, the split as file lists.
json nerfstudio_json(const std::vector<Camera>& train, const std::vector<Camera>& test, bool train_masks) {
  const Camera& c = train.front();
  json j{{"w", c.width},
         {"h", c.height},
         {"fl_x", c.focal},
         {"fl_y", c.focal},
         {"cx", 0.5 * c.width},
         {"cy", 0.5 * c.height},
         {"camera_model", c.lens.distorted() ? "OPENCV" : "PINHOLE"}};
  if (c.lens.distorted()) {
    j["k1"] = c.lens.k1;
    j["k2"] = c.lens.k2;
    j["p1"] = c.lens.p1;
    j["p2"] = c.lens.p2;
  }
  json frames = json::array(), train_files = json::array(), test_files = json::array();
  for (size_t k = 0; k < train.size(); ++k) {
    const std::string path = "train/r_" + std::to_string(k) + ".png";
    json f{{"file_path", path}, {"transform_matrix", pose_json(train[k])}};
    if (train_masks) f["mask_path"] = "train/r_" + std::to_string(k) + "_mask.png";
    frames.push_back(f);
    train_files.push_back(path);
  }
  for (size_t k = 0; k < test.size(); ++k) {
    const std::string base = "test/r_" + std::to_string(k);
    frames.push_back({{"file_path", base + ".png"},
                      {"depth_file_path", base + "_depth.pt"},
                      {"transform_matrix", pose_json(test[k])}});
    test_files.push_back(base + ".png");
  }
  j["frames"] = frames;
  j["train_filenames"] = train_files;
  j["test_filenames"] = test_files;
  return j;
}

// The demo's objects, lighting, background and cameras.
json demo_scene_json(const SynthOptions& o) {
  json objects = json::array();
  for (const Sphere& s : scene_spheres()) {
    json j{{"name", s.name},
           {"shape", "sphere"},
           {"material", material_name(s.material)},
           {"centre", vec_json(s.centre)},
           {"radius", s.radius}};
    if (s.material == MaterialKind::Mirror) j["reflectance_f0"] = vec_json(mirror_f0());
    if (s.material == MaterialKind::Glass) {
      j["ior"] = kGlassIor;
      j["fresnel"] = "exact dielectric";
      j["absorption_per_unit"] = vec_json(glass_absorption());
    }
    if (s.material == MaterialKind::Diffuse) j["texture"] = "longitude/latitude checker";
    objects.push_back(j);
  }
  return json{
      {"background",
       o.background == "environment" ? "the environment (sky and ground at infinity), alpha 1" : "transparent"},
      {"objects", objects},
      {"lighting",
       {{"environment", "sky gradient + azimuthal colour band + sun disc + checkered ground"},
        {"sun_direction", vec_json(sun_direction())},
        {"sun_irradiance", vec_json(sun_irradiance())},
        {"sun_radiance", vec_json(sun_radiance())},
        {"sun_angular_radius_deg", kSunAngularRadiusDeg},
        {"glass_shadow_transmittance", kGlassShadowTransmittance}}},
      {"cameras",
       {{"camera_angle_x", kCameraAngleX},
        {"distance", kCameraDistance},
        {"train",
         {{"layout", "golden-angle spiral, uniform by area"}, {"elevation_deg", {kMinElevationDeg, kMaxElevationDeg}}}},
        {"test", {{"layout", "orbit"}, {"elevation_deg", kTestElevationDeg}}}}},
  };
}

// The room's box, furniture, lighting and cameras.
json room_scene_json() {
  json faces = json::array();
  const char* textures[kRoomFaces] = {
      "wood planks 0.25 wide along x, boards 1.2 long with their own tones, grain, dark gaps",
      "light grey, faint grid of 0.5",
      "blue-grey checker of 0.2, pictures",
      "ochre vertical stripes of 0.3, pictures",
      "green checker of 0.4, pictures",
      "pink diagonal stripes of 0.35, pictures"};
  for (int f = 0; f < kRoomFaces; ++f) faces.push_back({{"name", kRoomFaceNames[f]}, {"texture", textures[f]}});
  json objects = json::array();
  for (const Box& b : room_furniture()) {
    json j = box_json(b.lo, b.hi);
    j["name"] = b.name;
    j["shape"] = "box";
    j["material"] = "diffuse";
    j["texture"] = "checker on each face";
    objects.push_back(j);
  }
  const Sphere& ball = room_ball();
  objects.push_back({{"name", ball.name},
                     {"shape", "sphere"},
                     {"material", "diffuse"},
                     {"centre", vec_json(ball.centre)},
                     {"radius", ball.radius},
                     {"texture", "longitude/latitude checker"}});
  json lights = json::array();
  for (const PointLight& l : room_lights())
    lights.push_back({{"name", l.name}, {"position", vec_json(l.position)}, {"intensity", vec_json(l.intensity)}});
  json room = box_json(kRoomMin, kRoomMax);
  room["seen_from"] = "inside";
  room["faces"] = faces;
  return json{
      {"background", "none: the room is closed, every pixel sees a surface (alpha 1)"},
      {"room", room},
      {"objects", objects},
      {"lighting",
       {{"model", "albedo * (ambient + sum of intensity * max(0, cos) / max(d^2, min_distance^2) * visible)"},
        {"ambient", vec_json(room_ambient())},
        {"point_lights", lights},
        {"min_distance", kRoomLightMinDistance},
        {"shadows", "hard, from every light, cast by the furniture and the ball"},
        {"albedo_range", {kRoomAlbedoMin, kRoomAlbedoMax}}}},
      {"cameras",
       {{"camera_angle_x", kRoomCameraAngleX},
        {"position",
         {{"layout", "uniform over a disc around the room's vertical axis, on the half the camera faces"},
          {"disc_centre", {0.0, 0.0}},
          {"radius", kRoomCameraRadius},
          {"height", {kRoomCameraMinHeight, kRoomCameraMaxHeight}}}},
        {"yaw_deg", {0.0, 360.0}},
        {"pitch_deg", {kRoomMinPitchDeg, kRoomMaxPitchDeg}},
        {"roll_deg", 0.0},
        {"train", "drawn from the seed"},
        {"test", "drawn alike from a stream of their own (seeded by the seed)"}}},
  };
}

json scene_json(const SynthOptions& o) {
  json j{
      {"generator", "ablenerf synth"},
      {"scene", o.scene},
      {"seed", o.seed},
      {"lens", o.lens == "opencv" ? json{{"model", "OPENCV"},
                                         {"k1", kWideLens.k1},
                                         {"k2", kWideLens.k2},
                                         {"p1", kWideLens.p1},
                                         {"p2", kWideLens.p2}}
                                  : json{{"model", "PINHOLE"}}},
      {"layout", o.resolved_layout()},
      {"resolution", {o.res, o.res}},
      {"train_views", o.train_views},
      {"test_views", o.test_views},
      {"render",
       {{"subsamples_per_pixel", kSubsamplesPerAxis * kSubsamplesPerAxis},
        {"alpha", "fraction of sub-samples that hit; RGB = mean over hit sub-samples (straight)"},
        {"colour", "linear, clamped per sub-sample, sRGB-encoded 8-bit"}}},
      {"depth", "t of the pixel-centre ray (depth along the optical axis), 0 on a miss"},
  };
  j.update(o.scene == "room" ? room_scene_json() : demo_scene_json(o));
  if (o.scene != "room") j["render"]["max_bounces"] = kMaxBounces;  // the room has no reflections
  return j;
}

void write_depth(const std::string& base, const ViewImage& img, double near, double far) {
  const auto depth =
      torch::from_blob(const_cast<float*>(img.depth.data()), {img.height, img.width}, torch::kFloat).clone();
  const std::vector<char> bytes = torch::pickle_save(depth);
  write_file_atomic(base + "_depth.pt", {bytes.data(), bytes.size()});
  auto grey = torch::zeros({img.height, img.width, 1}, torch::kFloat);
  auto acc = grey.accessor<float, 3>();
  for (int j = 0; j < img.height; ++j)
    for (int i = 0; i < img.width; ++i) {
      const double d = img.depth[static_cast<size_t>(j) * img.width + i];
      if (d <= 0.0) continue;
      const double s = std::clamp((far - d) / (far - near), 0.0, 1.0);
      acc[j][i][0] = static_cast<float>(kDepthGreyFar + (1.0 - kDepthGreyFar) * s);
    }
  write_png(base + "_depth.png", grey);
}

struct Job {
  const Camera* cam;
  std::string base;  // path without extension
  bool depth;
  Vec3 gain{1, 1, 1};
  const Distractor* distractor = nullptr;  // with one, the mask is written too
};

// What the train views' photos went through (SynthOptions): per view, the colour gains and the
// pose the image was rendered from (the written pose is the perturbed one).
struct ViewTruth {
  Vec3 gain{1, 1, 1};
  double exposure_stops = 0, red_stops = 0, blue_stops = 0;
  Camera true_camera;
};

constexpr uint64_t kJitterSeedSalt = 0x6a09e667f3bcc909ULL;  // a stream apart from the cameras'

double uniform_pm(std::mt19937_64& rng, double s) {
  return s * (2.0 * static_cast<double>(rng() >> 11) * 0x1.0p-53 - 1.0);
}

// n draws uniform in [-s, s], then centred so that their mean is exactly 0.
std::vector<double> centred_draws(std::mt19937_64& rng, size_t n, double s) {
  std::vector<double> v(n);
  double mean = 0;
  for (auto& x : v) mean += (x = uniform_pm(rng, s));
  mean /= static_cast<double>(n);
  for (auto& x : v) x -= mean;
  return v;
}

// A unit vector uniform on the sphere.
Vec3 random_direction(std::mt19937_64& rng) {
  const double z = uniform_pm(rng, 1.0), phi = M_PI * uniform_pm(rng, 1.0);
  const double r = std::sqrt(std::max(0.0, 1 - z * z));
  return {r * std::cos(phi), r * std::sin(phi), z};
}

// Rodrigues' rotation of v about the unit axis by angle (radians).
Vec3 rotate(const Vec3& v, const Vec3& axis, double angle) {
  return v * std::cos(angle) + cross(axis, v) * std::sin(angle) + axis * (dot(axis, v) * (1 - std::cos(angle)));
}

// The distance a camera's pose noise shift is a fraction of (SynthOptions::pose_noise_shift): the
// demo camera's from the origin it looks at, the room camera's from the first surface along its
// optical axis (its centre ray has a unit direction there, so t is that distance).
double view_distance(const Camera& c, bool room) {
  return room ? intersect_room(camera_ray(c, 0.5 * c.width, 0.5 * c.height)).t : length(c.centre());
}

// The train views' gains and perturbed poses (cams are changed in place; the truth is returned).
std::vector<ViewTruth> jitter_train_views(std::vector<Camera>& cams, const SynthOptions& o) {
  std::mt19937_64 rng(o.seed ^ kJitterSeedSalt);
  const size_t n = cams.size();
  const auto exposure = centred_draws(rng, n, o.exposure_jitter);
  const auto red = centred_draws(rng, n, o.white_balance_jitter);
  const auto blue = centred_draws(rng, n, o.white_balance_jitter);
  std::vector<ViewTruth> truth(n);
  for (size_t k = 0; k < n; ++k) {
    ViewTruth& t = truth[k];
    t.exposure_stops = exposure[k];
    t.red_stops = red[k];
    t.blue_stops = blue[k];
    const double g = std::exp2(exposure[k]);
    t.gain = {g * std::exp2(red[k]), g, g * std::exp2(blue[k])};
    t.true_camera = cams[k];
    const Vec3 axis = random_direction(rng), shift_dir = random_direction(rng);
    Camera& c = cams[k];
    const double angle = o.pose_noise_deg * M_PI / 180.0;
    for (int col = 0; col < 3; ++col) {
      const Vec3 turned = rotate(c.axis(col), axis, angle);
      for (int r = 0; r < 3; ++r) c.c2w[r][col] = turned[static_cast<size_t>(r)];
    }
    const Vec3 centre = c.centre() + shift_dir * (o.pose_noise_shift * view_distance(t.true_camera, o.scene == "room"));
    for (int r = 0; r < 3; ++r) c.c2w[r][3] = centre[static_cast<size_t>(r)];
  }
  return truth;
}

constexpr uint64_t kDistractorSeedSalt = 0xbb67ae8584caa73bULL;

// Each train view's ball: on the line from the camera to the origin, 50-65% of the way from the
// origin (clear of the objects, which lie within kSceneBound), moved sideways by up to 0.3.
std::vector<Distractor> place_distractors(const std::vector<Camera>& cams, uint64_t seed) {
  std::mt19937_64 rng(seed ^ kDistractorSeedSalt);
  std::vector<Distractor> out;
  for (const Camera& c : cams) {
    const double along = 0.575 + uniform_pm(rng, 0.075);
    Vec3 side = random_direction(rng);
    const Vec3 axis = c.centre() / length(c.centre());
    side = side - axis * dot(side, axis);
    out.push_back({c.centre() * along + side * 0.3, kDistractorRadius});
  }
  return out;
}

json truth_json(const std::vector<ViewTruth>& truth) {
  json views = json::array();
  for (const ViewTruth& t : truth)
    views.push_back({{"gain_rgb", vec_json(t.gain)},
                     {"exposure_stops", t.exposure_stops},
                     {"red_stops", t.red_stops},
                     {"blue_stops", t.blue_stops},
                     {"true_transform_matrix", pose_json(t.true_camera)}});
  return views;
}

// The room's stand-in for a structure-from-motion point cloud (nerfstudio's sparse_pc.ply beside
// transforms.json): the first surface hit by every kSparsePointStride-th pixel's ray, in each
// kSparsePointStride-th training view, as ASCII PLY. Points on surfaces the photos see, as SfM's
// are, without its noise or gaps.
constexpr const char* kSparsePointsFile = "sparse_pc.ply";
constexpr int kSparsePointStride = 8;

std::vector<Camera> true_cameras(const std::vector<ViewTruth>& truth) {
  std::vector<Camera> out;
  for (const ViewTruth& t : truth) out.push_back(t.true_camera);
  return out;
}

std::string sparse_points_ply(const std::vector<Camera>& cams, const SceneTracer& tracer) {
  std::vector<Vec3> points;
  for (size_t v = 0; v < cams.size(); v += kSparsePointStride) {
    const Camera& c = cams[v];
    for (int y = kSparsePointStride / 2; y < c.height; y += kSparsePointStride)
      for (int x = kSparsePointStride / 2; x < c.width; x += kSparsePointStride) {
        const Ray r = camera_ray(c, x + 0.5, y + 0.5);
        const Hit h = tracer.intersect(r, 0.0);
        if (h.hit()) points.push_back(r.at(h.t));
      }
  }
  std::ostringstream o;
  o.precision(9);
  o << "ply\nformat ascii 1.0\nelement vertex " << points.size()
    << "\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
  for (const Vec3& p : points) o << p.x << " " << p.y << " " << p.z << "\n";
  return o.str();
}

}  // namespace

std::string SynthOptions::resolved_layout() const {
  if (layout != "auto") return layout;
  return scene == "room" || lens != "pinhole" || background != "transparent" ? "nerfstudio" : "blender";
}

void validate(const SynthOptions& o) {
  if (o.scene != "demo" && o.scene != "room") throw InputError("synth", "--scene", "must be demo or room");
  if (o.lens != "pinhole" && o.lens != "opencv") throw InputError("synth", "--lens", "must be pinhole or opencv");
  if (o.background != "transparent" && o.background != "environment")
    throw InputError("synth", "--background", "must be transparent or environment");
  if (o.layout != "auto" && o.layout != "blender" && o.layout != "nerfstudio")
    throw InputError("synth", "--layout", "must be auto, blender or nerfstudio");
  if (o.layout == "blender" && o.lens != "pinhole")
    throw InputError("synth", "--layout", "the Blender layout has no lens model (use nerfstudio)");
  if (o.scene == "room") {
    if (o.background != "transparent")
      throw InputError("synth", "--background", "the room is closed: nothing lies behind its walls");
    if (o.distractor) throw InputError("synth", "--distractor", "only for the demo scene, not the room");
    if (o.layout == "blender")
      throw InputError("synth", "--layout", "the room is a real capture, not a Blender object scene (use nerfstudio)");
  }
  if (o.res < kMinResolution || o.res > kMaxResolution)
    throw InputError("synth", "--res",
                     "must be between " + std::to_string(kMinResolution) + " and " + std::to_string(kMaxResolution) +
                         " (got " + std::to_string(o.res) + ")");
  if (o.train_views < 1 || o.train_views > kMaxViews)
    throw InputError("synth", "--train-views", "must be between 1 and " + std::to_string(kMaxViews));
  if (o.test_views < 1 || o.test_views > kMaxViews)
    throw InputError("synth", "--test-views", "must be between 1 and " + std::to_string(kMaxViews));
  const auto in_range = [](double v, double hi) { return std::isfinite(v) && v >= 0 && v <= hi; };
  const std::string stops = "must be between 0 and " + std::to_string(static_cast<int>(kMaxJitterStops)) + " stops";
  if (!in_range(o.exposure_jitter, kMaxJitterStops)) throw InputError("synth", "--exposure-jitter", stops);
  if (!in_range(o.white_balance_jitter, kMaxJitterStops)) throw InputError("synth", "--white-balance-jitter", stops);
  if (!in_range(o.pose_noise_deg, kMaxPoseNoiseDeg))
    throw InputError("synth", "--pose-noise-deg",
                     "must be between 0 and " + std::to_string(static_cast<int>(kMaxPoseNoiseDeg)) + " degrees");
  if (!in_range(o.pose_noise_shift, kMaxPoseNoiseShift))
    throw InputError("synth", "--pose-noise-shift", "must be between 0 and 0.5 of the camera distance");
}

void write_synthetic_dataset(const std::string& dir, const SynthOptions& o) {
  validate(o);
  ensure_dir(dir + "/train");
  ensure_dir(dir + "/test");
  const bool room = o.scene == "room";
  const SceneTracer tracer = room ? room_tracer() : demo_tracer();
  std::vector<Camera> train =
      room ? room_train_cameras(o.train_views, o.res, o.seed) : train_cameras(o.train_views, o.res, o.seed);
  std::vector<Camera> test = room ? room_test_cameras(o.test_views, o.res, o.seed) : test_cameras(o.test_views, o.res);
  const double depth_near = room ? kRoomDepthNear : kCameraDistance - kSceneBound;
  const double depth_far = room ? kRoomDepthFar : kCameraDistance + kSceneBound;
  if (o.lens == "opencv")
    for (auto* cams : {&train, &test})
      for (auto& c : *cams) c.lens = kWideLens;
  const bool environment = o.background == "environment";
  const bool jittered =
      o.exposure_jitter > 0 || o.white_balance_jitter > 0 || o.pose_noise_deg > 0 || o.pose_noise_shift > 0;
  // The images are rendered from the true cameras; `train` then holds the poses written.
  std::vector<ViewTruth> truth;
  if (jittered) truth = jitter_train_views(train, o);
  std::vector<Distractor> balls;
  if (o.distractor) balls = place_distractors(train, o.seed);
  std::vector<Job> jobs;
  for (size_t k = 0; k < train.size(); ++k)
    jobs.push_back({jittered ? &truth[k].true_camera : &train[k], dir + "/train/r_" + std::to_string(k), false,
                    jittered ? truth[k].gain : Vec3{1, 1, 1}, o.distractor ? &balls[k] : nullptr});
  for (size_t k = 0; k < test.size(); ++k) jobs.push_back({&test[k], dir + "/test/r_" + std::to_string(k), true});

  // Workers take whole views (render + encode + write), which keeps PNG encoding and file
  // syncing parallel too. Each view's pixels depend only on its camera: thread-count independent.
  int threads = o.threads > 0 ? o.threads : static_cast<int>(std::max(2u, std::thread::hardware_concurrency()));
  threads = std::min<int>(threads, static_cast<int>(jobs.size()));
  std::atomic<size_t> next{0};
  std::mutex mu;
  int done = 0;
  std::exception_ptr failure;
  auto worker = [&] {
    for (size_t k = next++; k < jobs.size(); k = next++) {
      try {
        const ViewImage img = render_view(*jobs[k].cam, 1, environment, jobs[k].gain, jobs[k].distractor, tracer);
        const auto rgba =
            torch::from_blob(const_cast<float*>(img.rgba.data()), {img.height, img.width, 4}, torch::kFloat);
        write_png(jobs[k].base + ".png", rgba);
        if (jobs[k].distractor) {
          const auto ball =
              torch::from_blob(const_cast<uint8_t*>(img.distractor.data()), {img.height, img.width, 1}, torch::kUInt8);
          write_png(jobs[k].base + "_mask.png", (1 - ball.to(torch::kFloat)).expand({-1, -1, 3}).contiguous());
        }
        if (jobs[k].depth) write_depth(jobs[k].base, img, depth_near, depth_far);
      } catch (...) {
        std::lock_guard<std::mutex> lock(mu);
        if (!failure) failure = std::current_exception();
        next = jobs.size();  // stop the other workers early
        return;
      }
      std::lock_guard<std::mutex> lock(mu);
      ++done;
      if (o.progress) o.progress(done, static_cast<int>(jobs.size()));
    }
  };
  std::vector<std::thread> pool;
  for (int t = 0; t < threads; ++t) pool.emplace_back(worker);
  for (auto& th : pool) th.join();
  if (failure) std::rethrow_exception(failure);

  // The json files go last, so a readable transforms file implies its images exist.
  if (o.resolved_layout() == "nerfstudio") {
    json transforms = nerfstudio_json(train, test, o.distractor);
    if (room) {
      write_file_atomic(dir + "/" + kSparsePointsFile,
                        sparse_points_ply(jittered ? true_cameras(truth) : train, tracer));
      transforms["ply_file_path"] = kSparsePointsFile;
    }
    write_file_atomic(dir + "/transforms.json", transforms.dump(2) + "\n");
  } else {
    write_file_atomic(dir + "/transforms_train.json",
                      transforms_json(train, "train", false, o.distractor).dump(2) + "\n");
    write_file_atomic(dir + "/transforms_test.json", transforms_json(test, "test", true, false).dump(2) + "\n");
  }
  json scene = scene_json(o);
  if (jittered) {
    scene["train_jitter"] = {{"exposure_stops", o.exposure_jitter},
                             {"white_balance_stops", o.white_balance_jitter},
                             {"pose_noise_deg", o.pose_noise_deg},
                             {"pose_noise_shift", o.pose_noise_shift}};
    scene["train_view_truth"] = truth_json(truth);
  }
  if (o.distractor) {
    json list = json::array();
    for (const Distractor& b : balls) list.push_back({{"centre", vec_json(b.centre)}, {"radius", b.radius}});
    scene["train_distractors"] = {{"colour_linear", vec_json(distractor_colour())}, {"balls", list}};
  }
  write_file_atomic(dir + "/scene.json", scene.dump(2) + "\n");
}

}  // namespace ablenerf::synth
