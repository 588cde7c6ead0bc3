#include "view/view_session.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>

#include "data/ply.h"
#include "eval/colormap.h"
#include "eval/evaluate.h"
#include "eval/renderer.h"
#include "model/look.h"
#include "train/trainer.h"
#include "util/image_io.h"
#include "util/png_codec.h"
#include "eval/eval_config.h"
#include "data/data_config.h"
#include "model/model_config.h"

namespace ablenerf {

void LiveControl::pause() {
  const std::lock_guard<std::mutex> lock(mu_);
  paused_ = true;
}

void LiveControl::resume() {
  {
    const std::lock_guard<std::mutex> lock(mu_);
    paused_ = false;
  }
  cv_.notify_all();
}

void LiveControl::request_save() {
  const std::lock_guard<std::mutex> lock(mu_);
  save_ = true;
}

bool LiveControl::paused() const {
  const std::lock_guard<std::mutex> lock(mu_);
  return paused_;
}

bool LiveControl::take_save() {
  const std::lock_guard<std::mutex> lock(mu_);
  const bool s = save_;
  save_ = false;
  return s;
}

bool LiveControl::wait_if_paused(std::chrono::milliseconds at_most) {
  std::unique_lock<std::mutex> lock(mu_);
  if (paused_) cv_.wait_for(lock, at_most, [this] { return !paused_; });
  return paused_;
}

void view_between_steps(Trainer& trainer, ViewSession& session, LiveControl& control) {
  if (session.wants_weights()) session.set_weights(trainer.model(), trainer.steps_done());
  do {
    if (control.take_save()) trainer.checkpoint_now();
  } while (control.wait_if_paused(std::chrono::milliseconds(100)) && !interrupt_requested());
}

ViewSession::ViewSession(const std::string& run_dir, const torch::Device& device, bool live)
    : run_(RunFolder::open(run_dir)), device_(device), live_(live) {
  scene_ = run_.scene();
  if (run_.data_dir.empty())
    throw InputError(run_.path("run.json"), "data", "no dataset recorded: the viewer needs its cameras");
  Capture capture = read_capture(run_.data_dir, {}, run_.config.get<DataConfig>().downscale);
  cams_ = capture_cameras(capture, scene_, run_.config.get<DataConfig>().downscale);
  capture_h_ = capture.height;
  capture_w_ = capture.width;
  for (auto& split : capture.splits)
    for (auto& f : split.frames) {
      // The train split's photos in training order: the per-photo colour maps' and appearance codes'
      // (model/look.h).
      if (split.name == "train") looks_.push_back(std::filesystem::path(f.image).filename().string());
      frames_.push_back(std::move(f));
    }
  if (live_) {
    model_ = AbleNerf(run_.config.get<ModelConfig>(), scene_.kind, NdcProjection{scene_.ndc_a, scene_.ndc_b});
    model_->to(device_);
    wants_ = true;  // the first render needs the trainer's weights
  } else {
    model_ = load_run_model(run_, device_);
  }
  model_->eval();
  if (look_photos(*model_) == 0) looks_.clear();  // no per-photo colour or codes, no looks to offer
}

void ViewSession::set_weights(AbleNerf& trained, int64_t step) {
  const std::lock_guard<std::mutex> lock(mu_);
  const torch::NoGradGuard no_grad;
  const auto src = trained->named_parameters(), dst = model_->named_parameters();
  // The per-photo parameters (colour maps, camera corrections, appearance codes) exist only in the
  // trainer's model: the live view shows the photos' mean look. Any other name must match.
  for (const auto& p : src)
    if (!AbleNerfImpl::per_photo_parameter(p.key())) dst[p.key()].copy_(p.value());
  const auto sb = trained->named_buffers(), db = model_->named_buffers();
  for (const auto& b : sb) db[b.key()].copy_(b.value());
  step_ = step;
  copies_ += 1;
  wants_ = false;
}

nlohmann::json ViewSession::cameras_json() const {
  nlohmann::json j;
  j["scene"] = name_of(scene_.kind);
  j["near"] = scene_.near;
  j["far"] = scene_.far;
  const Intrinsics& k = cams_.intrinsics;
  j["width"] = k.width;
  j["height"] = k.height;
  j["fx"] = k.fx;
  j["fy"] = k.fy;
  nlohmann::json list = nlohmann::json::array();
  const auto c2w = cams_.c2w.to(torch::kFloat).contiguous();
  for (int64_t i = 0; i < c2w.size(0); ++i) {
    const float* p = c2w[i].data_ptr<float>();
    list.push_back(std::vector<float>(p, p + 12));
  }
  j["cameras"] = list;
  j["live"] = live_;
  j["looks"] = looks_;
  return j;
}

nlohmann::json ViewSession::points_json(int64_t max_points) const {
  nlohmann::json out{{"count", 0}, {"points", nlohmann::json::array()}};
  try {
    const auto all = run_.exports();
    for (auto e = all.rbegin(); e != all.rend(); ++e) {
      if (!e->is_object() || !e->contains("points") || !(*e)["points"].contains("path")) continue;
      const std::string path = (*e)["points"]["path"].get<std::string>();
      const bool capture_frame = e->value("frame", std::string("capture")) == "capture";
      const auto pts = read_ply_points(path);
      const int64_t n = static_cast<int64_t>(pts.size());
      const int64_t stride = std::max<int64_t>(1, (n + max_points - 1) / std::max<int64_t>(max_points, 1));
      std::vector<float> flat;
      for (int64_t i = 0; i < n; i += stride) {
        const auto p = capture_frame ? scene_.point_to_scene(pts[static_cast<size_t>(i)]) : pts[static_cast<size_t>(i)];
        for (const double x : p) flat.push_back(static_cast<float>(x));
      }
      out["file"] = path;
      out["count"] = n;
      out["points"] = flat;
      return out;
    }
  } catch (const std::exception& e) {
    out["note"] = std::string("exported points not read: ") + e.what();
  }
  return out;
}

int ViewSession::nearest_camera(const std::array<float, 12>& c2w) const {
  const auto all = cams_.c2w.to(torch::kFloat).contiguous();
  int best = 0;
  double best_d = 1e300;
  for (int64_t i = 0; i < all.size(0); ++i) {
    const float* p = all[i].data_ptr<float>();
    double d2 = 0, cosang = 0;
    for (int r = 0; r < 3; ++r) {
      d2 += (p[r * 4 + 3] - c2w[static_cast<size_t>(r * 4 + 3)]) * (p[r * 4 + 3] - c2w[static_cast<size_t>(r * 4 + 3)]);
      cosang += p[r * 4 + 2] * c2w[static_cast<size_t>(r * 4 + 2)];
    }
    const double d = std::sqrt(d2) + std::acos(std::clamp(cosang, -1.0, 1.0));
    if (d < best_d) best_d = d, best = static_cast<int>(i);
  }
  return best;
}

std::string ViewSession::render_png(const std::array<float, 12>& asked, int width, int height, ViewMode mode,
                                    int* camera, int look) {
  const PhotoLook chosen = photo_look(*model_, look, "request", "look");
  const Intrinsics& d = cams_.intrinsics;
  Intrinsics k;  // the dataset's focal at this width, a pinhole
  k.width = width;
  k.height = height;
  k.fx = d.fx * width / d.width;
  k.fy = d.fy * width / d.width;
  k.cx = 0.5 * width;
  k.cy = 0.5 * height;
  std::array<float, 12> c2w = asked;
  torch::Tensor truth;  // ViewMode::Error: the nearest camera's image at this size, composited
  if (mode == ViewMode::Error) {
    const int i = nearest_camera(asked);
    if (camera) *camera = i;
    const auto p = cams_.c2w[i].to(torch::kFloat).contiguous();
    std::memcpy(c2w.data(), p.data_ptr<float>(), sizeof(float) * 12);
    const CaptureFrame& f = frames_.at(static_cast<size_t>(i));
    k = f.camera.scaled(static_cast<double>(width) / f.camera.width, width, height);
    // The photo as the loader reads it (upright, at the run's downscale), straight RGBA averaged
    // over areas to the asked size (as the loader's box downscale), then composited.
    auto rgba = frame_photo_rgba(f, capture_h_, capture_w_, run_.config.get<DataConfig>().downscale);
    rgba = torch::nn::functional::interpolate(rgba.permute({2, 0, 1}).unsqueeze(0),
                                              torch::nn::functional::InterpolateFuncOptions()
                                                  .size(std::vector<int64_t>{height, width})
                                                  .mode(torch::kArea))
               .squeeze(0)
               .permute({1, 2, 0});
    const float bg = run_.config.get<DataConfig>().background == Background::White ? 1.0f : 0.0f;
    const auto a = rgba.slice(2, 3, 4);
    truth = rgba.slice(2, 0, 3) * a + bg * (1 - a);
  }
  auto pose = torch::empty({3, 4}, torch::kFloat);
  std::memcpy(pose.data_ptr<float>(), c2w.data(), sizeof(float) * 12);
  torch::Tensor image;
  if (live_) wants_ = true;  // the next pause between steps brings newer weights
  {
    const std::lock_guard<std::mutex> lock(mu_);
    const torch::NoGradGuard no_grad;
    ForwardOptions fo;
    fo.appearance = chosen.appearance;  // the chosen photo's code, if the run learnt codes
    const RenderResult r = render_image(model_, pose.to(device_), k, scene_.near, scene_.far,
                                        run_.config.get<EvalConfig>().chunk, fo, device_);
    if (mode == ViewMode::Rgb) {
      image = r.rgb;
      if (chosen.colour) image = chosen.colour->look(image, chosen.photo);  // its colour map over every pixel
    } else if (mode == ViewMode::Error) {
      image = colormap((r.rgb.to(torch::kCPU) - truth).abs().mean(-1), 0.0, kErrorMapMax);
    } else {
      // As eval's depth maps: unbounded scenes up to twice the cameras' sphere.
      const double far = scene_.kind == SceneKind::Unbounded ? 2.0 : scene_.far;
      image = colormap(r.depth_front, scene_.near, far);  // the attention's front (docs/MODEL.md, section 9)
    }
  }
  const auto u8 = to_uint8(image.to(torch::kCPU)).contiguous();
  return encode_png(width, height, 3, u8.data_ptr<uint8_t>());
}

}  // namespace ablenerf
