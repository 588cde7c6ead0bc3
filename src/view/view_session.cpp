#include "view/view_session.h"

#include <cstring>

#include "eval/colormap.h"
#include "eval/renderer.h"
#include "util/image_io.h"
#include "util/png_codec.h"

namespace ablenerf {

ViewSession::ViewSession(const std::string& run_dir, const torch::Device& device)
    : run_(RunFolder::open(run_dir)), device_(device) {
  scene_ = run_.scene();
  if (run_.data_dir.empty()) throw InputError(run_.path("run.json"), "data", "no dataset recorded: the viewer needs its cameras");
  cams_ = capture_cameras(run_.data_dir, scene_, run_.config.data.downscale);
  model_ = load_run_model(run_, device_);
  model_->eval();
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
  return j;
}

std::string ViewSession::render_png(const std::array<float, 12>& c2w, int width, int height, ViewMode mode) {
  const Intrinsics& d = cams_.intrinsics;
  Intrinsics k;  // the dataset's focal at this width, a pinhole
  k.width = width;
  k.height = height;
  k.fx = d.fx * width / d.width;
  k.fy = d.fy * width / d.width;
  k.cx = 0.5 * width;
  k.cy = 0.5 * height;
  auto pose = torch::empty({3, 4}, torch::kFloat);
  std::memcpy(pose.data_ptr<float>(), c2w.data(), sizeof(float) * 12);
  torch::Tensor image;
  {
    const std::lock_guard<std::mutex> lock(mu_);
    const torch::NoGradGuard no_grad;
    const RenderResult r =
        render_image(model_, pose.to(device_), k, scene_.near, scene_.far, run_.config.eval.chunk, ForwardOptions{}, device_);
    if (mode == ViewMode::Rgb) {
      image = r.rgb;
    } else {
      // As eval's depth maps: unbounded scenes up to twice the cameras' sphere.
      const double far = scene_.kind == SceneKind::Unbounded ? 2.0 : scene_.far;
      image = colormap(r.depth_mean, scene_.near, far);
    }
  }
  const auto u8 = to_uint8(image.to(torch::kCPU)).contiguous();
  return encode_png(width, height, 3, u8.data_ptr<uint8_t>());
}

}  // namespace ablenerf
