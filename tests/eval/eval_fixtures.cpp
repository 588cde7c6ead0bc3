#include "eval_fixtures.h"

#include <cmath>
#include <filesystem>
#include <fstream>

#include "eval/camera_path.h"
#include "model/able_nerf.h"
#include "test_util.h"
#include "util/image_io.h"
#include "model/model_config.h"

namespace fs = std::filesystem;

namespace ablenerf::test {
namespace {
constexpr double kCameraDistance = 4.0;
constexpr double kCameraAngleX = 0.6911112070083618;  // the Blender scenes' field of view
constexpr int64_t kModelSeed = 7;

std::string pose_json(const torch::Tensor& p34) {
  std::string s = "[";
  for (int r = 0; r < 3; ++r) {
    s += "[";
    for (int c = 0; c < 4; ++c) s += std::to_string(p34[r][c].item<double>()) + (c < 3 ? "," : "");
    s += "],";
  }
  return s + "[0,0,0,1]]";
}

void write_split(const std::string& dir, const std::string& split, int n, int w, int h, double phase0,
                 bool with_depth) {
  fs::create_directories(dir + "/" + split);
  std::string frames;
  for (int i = 0; i < n; ++i) {
    const double az = phase0 + 2.0 * M_PI * i / n, el = 0.4;
    const auto eye = torch::tensor({kCameraDistance * std::cos(el) * std::cos(az),
                                    kCameraDistance * std::cos(el) * std::sin(az), kCameraDistance * std::sin(el)},
                                   torch::kDouble);
    const auto pose =
        ablenerf::look_at(eye, torch::zeros({3}, torch::kDouble), torch::tensor({0.0, 0.0, 1.0}, torch::kDouble));
    // Smooth colour ramps in the opaque left half, transparent right half.
    auto ys = torch::linspace(0, 1, h).view({h, 1}).expand({h, w});
    auto xs = torch::linspace(0, 1, w).view({1, w}).expand({h, w});
    auto alpha = (xs < 0.5).to(torch::kFloat);
    auto img = torch::stack({ys, xs, 0.5 * (ys + xs) + 0.1 * i, alpha}, -1).clamp(0, 1);
    const std::string name = split + "/r_" + std::to_string(i);
    write_png(dir + "/" + name + ".png", img);
    std::string extra;
    if (with_depth) {
      auto depth = torch::zeros({h, w});
      depth.slice(0, 0, h / 2).fill_(4.0f);
      const auto bytes = torch::pickle_save(depth);
      std::ofstream(dir + "/" + name + "_depth.pt", std::ios::binary)
          .write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
      extra = ", \"depth_file_path\": \"./" + name + "_depth.pt\"";
    }
    frames += std::string(i ? "," : "") + "{\"file_path\": \"./" + name +
              "\", \"transform_matrix\": " + pose_json(pose) + extra + "}";
  }
  write_file(dir + "/transforms_" + split + ".json",
             "{\"camera_angle_x\": " + std::to_string(kCameraAngleX) + ", \"frames\": [" + frames + "]}");
}
}  // namespace

void make_tiny_scene(const std::string& dir, int n_train, int n_test, int w, int h, bool with_depth) {
  write_split(dir, "train", n_train, w, h, 0.0, false);
  write_split(dir, "test", n_test, w, h, 0.3, with_depth);
}

RunFolder make_tiny_run(const std::string& run_dir, const std::string& data_dir) {
  const Config cfg = tiny_model_config();
  RunFolder run = RunFolder::create(run_dir, cfg, data_dir);
  torch::manual_seed(kModelSeed);
  AbleNerf model(cfg.get<ModelConfig>());
  save_weights(model, run.weights_path());
  std::string log;
  for (int step = 100; step <= 500; step += 100)
    log += "{\"type\":\"train\",\"step\":" + std::to_string(step) + ",\"loss\":" + std::to_string(0.1 / step * 100) +
           ",\"terms\":{\"fine\":" + std::to_string(0.07 / step * 100) +
           ",\"proposal\":" + std::to_string(0.03 / step * 100) + "},\"psnr\":" + std::to_string(10 + step / 100.0) +
           ",\"lr\":0.0005,\"rays_per_s\":1000,\"elapsed_s\":" + std::to_string(step / 10.0) + "}\n";
  log += "{\"type\":\"eval\",\"step\":500,\"psnr\":13.5,\"views\":4,\"split\":\"val\"}\n";
  write_file(run.log_path(), log);
  return run;
}

void give_run_appearance_codes(const std::string& run_dir, const torch::Tensor& codes) {
  const RunFolder run = RunFolder::open(run_dir);
  AbleNerf model = load_run_model(run, torch::kCPU);
  model->enable_appearance_code(codes.size(0));
  {
    const torch::NoGradGuard no_grad;
    model->appearance_code()->parameter().copy_(codes);
  }
  save_weights(model, run.weights_path());
}

}  // namespace ablenerf::test
