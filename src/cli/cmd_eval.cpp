// `ablenerf eval`: renders the first N views of a split with a run's model, scores them (PSNR,
// SSIM, LPIPS, depth error when known), writes RUN/eval/SPLIT/ (images, metrics.json) and
// rewrites RUN/report.html. The work is eval/evaluate.h; this file is option plumbing.
#include <iostream>
#include <memory>

#include "cli/command.h"
#include "cli/common.h"
#include "eval/evaluate.h"
#include "eval/report.h"
#include "util/errors.h"

namespace ablenerf::cli {
namespace cmd_eval {

struct EvalArgs {
  std::string run, split = "test", data, ssim, lpips_weights, device = "auto";
  int64_t max_images = -1, chunk = 0;  // -1: every view; chunk and downscale only when given
  int downscale = 0;
  bool align_cameras = false;
  bool fit_look = false;
  bool json = false;
};

void setup(CLI::App& app) {
  auto a = std::make_shared<EvalArgs>();
  app.add_option("--run", a->run, "Run folder written by `ablenerf train`")->required();
  app.add_option("--split", a->split, "Dataset split to evaluate")->capture_default_str();
  app.add_option("--max-images", a->max_images, "Evaluate only the first N views (default: all)")
      ->check(CLI::PositiveNumber);
  auto* downscale =
      app.add_option("--downscale", a->downscale, "Image downscale factor (default: the run's data.downscale)")
          ->check(CLI::PositiveNumber);
  app.add_option("--data", a->data, "Dataset folder (default: the one recorded in RUN/run.json)");
  app.add_option("--ssim", a->ssim,
                 "SSIM variant: standard (valid 11x11 window) or release (zero-padded, "
                 "the authors' code); default: the run's eval.ssim");
  app.add_option("--lpips-weights", a->lpips_weights,
                 "LPIPS AlexNet weights (default: $ABLENERF_LPIPS_WEIGHTS or shared/weights; none -> skipped)");
  auto* chunk = app.add_option("--chunk", a->chunk, "Rays per forward pass (default: the run's eval.chunk)")
                    ->check(CLI::PositiveNumber);
  app.add_option("--device", a->device, "cpu, cuda, cuda:N or auto (cuda when available)")->capture_default_str();
  app.add_flag("--align-cameras", a->align_cameras,
               "Fit each held-out camera to its photo with the model frozen before scoring (after "
               "train.camera_refine; default: the run's eval.align_cameras)");
  app.add_flag("--fit-look", a->fit_look,
               "NeRF-W's protocol: fit each view's exposure and white balance (an affine colour map), and its "
               "appearance code when the run has codes, on the left half of its photo, score the right half "
               "(default: the run's eval.fit_look)");
  add_json_flag(app, a->json);
  app.callback([a, downscale, chunk] {
    const torch::Device device = parse_device(a->device);
    const RunFolder run = RunFolder::open(a->run);
    EvalOptions o;
    o.split = a->split;
    o.max_images = a->max_images;
    if (downscale->count()) o.downscale = a->downscale;
    o.data_dir = a->data;
    o.ssim = a->ssim;
    o.lpips_weights = a->lpips_weights;
    if (chunk->count()) o.chunk = a->chunk;
    if (a->align_cameras) o.align_cameras = true;
    if (a->fit_look) o.fit_look = true;
    o.device = device;
    const auto m = evaluate_run(run, o);
    write_report(run);
    const auto& mean = m["mean"];
    const std::string metrics_path = eval_dir(run, a->split) + "/metrics.json";
    if (a->json) {
      std::cout << nlohmann::json{{"split", a->split},
                                  {"views", m["images"].size()},
                                  {"mean", mean},
                                  {"metrics", metrics_path},
                                  {"report", run.report_path()}}
                       .dump()
                << std::endl;
      return;
    }
    auto show = [](const nlohmann::json& v) {
      return v.is_number() ? std::to_string(v.get<double>()) : std::string("n/a");
    };
    std::cout << "eval " << a->split << ": " << m["images"].size() << " views  PSNR " << show(mean["psnr"]) << "  SSIM "
              << show(mean["ssim"]) << "  LPIPS " << show(mean["lpips"]);
    if (mean.contains("psnr_unmasked"))
      std::cout << "  unmasked PSNR " << show(mean["psnr_unmasked"]) << "  SSIM " << show(mean["ssim_unmasked"]);
    // The front's depth error: the mean and argmax depths of an unbounded scene reach its far
    // samples (1e6) on a few pixels, which rule their mean (all three are in metrics.json).
    if (mean.contains("depth_mae_front")) std::cout << "  depth MAE " << show(mean["depth_mae_front"]);
    std::cout << "\nwrote " << metrics_path << " and " << run.report_path() << std::endl;
  });
}

}  // namespace cmd_eval
ABLENERF_COMMAND("eval", 30, "Evaluate a run on a split (PSNR, SSIM, LPIPS, images, report)", cmd_eval::setup);
}  // namespace ablenerf::cli
