#include "eval/evaluate.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <optional>

#include "data/dataset.h"
#include "data/load_options.h"
#include "eval/camera_align.h"
#include "eval/look_fit.h"
#include "eval/colormap.h"
#include "eval/lpips.h"
#include "eval/metrics.h"
#include "eval/renderer.h"
#include "eval/report.h"
#include "run/run_log.h"
#include "util/errors.h"
#include "util/log.h"
#include "util/fs.h"
#include "util/image_io.h"
#include "util/progress.h"
#include "eval/eval_config.h"
#include "data/data_config.h"

namespace fs = std::filesystem;

namespace ablenerf {
namespace {

// JSON has no infinity/NaN: such scores are written as null.
nlohmann::json finite_or_null(double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(); }

// Mean of the non-null entries of images[*][key]; null when there are none or one is null
// for a reason that must not be averaged away (all-or-nothing keeps means comparable).
nlohmann::json mean_of(const nlohmann::json& images, const std::string& key) {
  double sum = 0;
  size_t n = 0;
  for (const auto& im : images) {
    if (!im.contains(key)) continue;
    if (im[key].is_null()) return nullptr;
    sum += im[key].get<double>();
    ++n;
  }
  return n ? nlohmann::json(sum / static_cast<double>(n)) : nlohmann::json();
}

std::string join(const std::vector<std::string>& v) {
  std::string s;
  for (const auto& x : v) s += (s.empty() ? "" : ", ") + x;
  return s;
}

}  // namespace

std::string eval_dir(const RunFolder& run, const std::string& split) { return run.path("eval/" + split); }

nlohmann::json evaluate_run(const RunFolder& run, const EvalOptions& opts) {
  std::function<void(const std::string&)> note = opts.note;
  if (!note) note = [](const std::string& s) { log_info(s); };
  const std::string data_dir = opts.data_dir.empty() ? run.data_dir : opts.data_dir;
  if (data_dir.empty()) throw InputError(run.path("run.json"), "data", "no dataset recorded (pass --data DIR)");
  if (!fs::is_directory(data_dir))
    throw InputError(data_dir, "",
                     std::string("dataset folder not found") +
                         (opts.data_dir.empty() ? " (recorded in run.json; pass --data DIR)" : ""));
  if (opts.chunk && *opts.chunk <= 0)
    throw InputError("--chunk", "", "must be positive (got " + std::to_string(*opts.chunk) + ")");
  if (opts.downscale && *opts.downscale <= 0)
    throw InputError("--downscale", "", "must be positive (got " + std::to_string(*opts.downscale) + ")");
  const SsimVariant variant =
      opts.ssim.empty() ? run.config.get<EvalConfig>().ssim : parse_ssim_variant(opts.ssim, "--ssim");
  const int64_t chunk = opts.chunk.value_or(run.config.get<EvalConfig>().chunk);
  const bool align = opts.align_cameras.value_or(run.config.get<EvalConfig>().align_cameras);
  CameraAlignOptions align_opts;
  align_opts.steps = run.config.get<EvalConfig>().align_steps;
  const bool fit_look = opts.fit_look.value_or(run.config.get<EvalConfig>().fit_look);
  PhotoFitOptions code_opts;
  code_opts.steps = run.config.get<EvalConfig>().look_code_steps;
  code_opts.lr = run.config.get<EvalConfig>().look_code_lr;

  LoadOptions lo = load_options_for(run.config, {opts.split});
  // The capture's masks score the "unmasked" part even for a run trained on every pixel
  // (data.masks = "none"), so that runs with and without masks compare on the same pixels.
  if (lo.masks == MaskSource::None) lo.masks = MaskSource::Auto;
  if (opts.downscale) lo.downscale = *opts.downscale;
  Capture capture = read_capture(data_dir, {}, lo.downscale);  // parsed once: its splits, then the load
  const auto splits = capture.split_names();
  if (std::find(splits.begin(), splits.end(), opts.split) == splits.end())
    throw InputError(data_dir, "--split",
                     "no split '" + opts.split + "'" + (splits.empty() ? "" : " (available: " + join(splits) + ")"));
  const Dataset ds = Dataset::load(std::move(capture), data_dir, lo);
  const Split& split = ds.split(opts.split);
  const Intrinsics& k = ds.intrinsics;

  AbleNerf model = load_run_model(run, opts.device);

  // LPIPS: explicit weights must load; otherwise the default location, if any.
  std::optional<Lpips> lpips;
  const std::string lpips_path = opts.lpips_weights.empty() ? default_lpips_weights_path() : opts.lpips_weights;
  if (lpips_path.empty()) {
    note("LPIPS skipped: no weights found (pass --lpips-weights FILE or set ABLENERF_LPIPS_WEIGHTS)");
  } else if (k.width < Lpips::kMinSide || k.height < Lpips::kMinSide) {
    note("LPIPS skipped: images are " + std::to_string(k.width) + "x" + std::to_string(k.height) +
         ", AlexNet needs at least " + std::to_string(Lpips::kMinSide) + " pixels a side");
  } else {
    lpips.emplace(lpips_path);
  }
  // With a fitted look the scores are the right half's (columns W/2 .. W-1).
  const int64_t scored_w = fit_look ? k.width - k.width / 2 : k.width;
  if (lpips && fit_look && scored_w < Lpips::kMinSide) {
    note("LPIPS skipped: the scored right halves are " + std::to_string(scored_w) + " pixels wide, AlexNet needs " +
         std::to_string(Lpips::kMinSide));
    lpips.reset();
  }
  const bool ssim_ok = variant != SsimVariant::Standard || (scored_w >= kSsimWindow && k.height >= kSsimWindow);
  if (!ssim_ok)
    note("SSIM skipped: the standard variant needs images of at least " + std::to_string(kSsimWindow) + "x" +
         std::to_string(kSsimWindow));

  const int64_t count = opts.max_images < 0 ? split.size() : std::min<int64_t>(opts.max_images, split.size());
  const std::string out_dir = eval_dir(run, opts.split);
  ensure_dir(out_dir);

  // Forward-facing models see depth as the NDC ray's t (disparity-like), not comparable to metric
  // ground truth: no depth error there.
  const bool has_depth = split.depth.defined() && ds.scene.kind != SceneKind::ForwardFacing;
  nlohmann::json images = nlohmann::json::array();
  const int64_t rays_per_image = static_cast<int64_t>(k.width) * k.height;
  std::optional<Progress> bar;
  if (opts.progress) bar.emplace("eval " + opts.split + " (rays)", count * rays_per_image);
  double total_seconds = 0;
  for (int64_t i = 0; i < count; ++i) {
    const std::string view = "view " + std::to_string(i + 1) + "/" + std::to_string(count);
    // A run that refined the capture's focal length renders every photo with it (model/camera_refine.h).
    const Intrinsics& given = split.cameras.empty() ? k : split.cameras[static_cast<size_t>(i)];
    const Intrinsics cam = model->camera_refine() ? model->camera_refine()->refined(given) : given;
    std::optional<CameraAlignment> aligned;
    if (align) {
      align_opts.seed = static_cast<uint64_t>(i);
      aligned = align_camera(model, split.c2w[i], cam, split.images[i],
                             split.mask.defined() ? split.mask[i] : torch::Tensor(), ds.near, ds.far, align_opts,
                             opts.device);
    }
    const torch::Tensor pose = aligned ? aligned->c2w : split.c2w[i];
    // NeRF-W: a run with appearance codes renders with the code fitted on the photo's left half.
    ForwardOptions look_opts;
    std::optional<CodeFit> code;
    if (fit_look && model->appearance_code()) {
      code_opts.seed = static_cast<uint64_t>(i);
      code =
          fit_code_left_half(model, pose, cam, split.images[i], split.mask.defined() ? split.mask[i] : torch::Tensor(),
                             ds.near, ds.far, code_opts, opts.device);
      look_opts.appearance = code->code;
    }
    const auto t0 = std::chrono::steady_clock::now();  // the render's time, the fits' aside
    const RenderResult r =
        render_image(model, pose, cam, ds.near, ds.far, chunk, look_opts, opts.device, [&](int64_t done, int64_t) {
          if (bar) bar->update(i * rays_per_image + done, view);
        });
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    total_seconds += seconds;
    torch::Tensor gt = split.images[i], rgb = r.rgb, keep = split.mask.defined() ? split.mask[i] : torch::Tensor();
    std::optional<LookFit> look;
    if (fit_look) {  // NeRF-W: the look from the left half, the scores from the right half
      look = fit_look_left_half(r.rgb, gt, keep);
      const int64_t half = k.width / 2;
      rgb = look->fitted.slice(1, half).contiguous();
      gt = gt.slice(1, half).contiguous();
      if (keep.defined()) keep = keep.slice(1, half).contiguous();
    }

    const std::string stem = out_dir + "/r_" + std::to_string(i);
    const torch::Tensor& shown = look ? look->fitted : r.rgb;  // the whole render, through the fitted map
    write_png(stem + ".png", shown);
    write_png(stem + "_gt.png", split.images[i]);
    write_png(stem + "_error.png", colormap((shown - split.images[i]).abs().mean(-1), 0.0, kErrorMapMax));
    // Unbounded scenes reach 1e6: their depth maps span near to the image's 98th percentile.
    const double depth_far = ds.scene.kind == SceneKind::Unbounded
                                 ? std::max(ds.near * 1.01, r.depth_front.flatten().quantile(0.98).item<double>())
                                 : ds.far;
    // The attention's front: where the surfaces are (docs/MODEL.md, section 9).
    write_png(stem + "_depth.png", colormap(r.depth_front, ds.near, depth_far));

    nlohmann::json im;
    im["index"] = i;
    im["file"] = split.files[static_cast<size_t>(i)];
    im["render"] = "r_" + std::to_string(i) + ".png";
    im["psnr"] = finite_or_null(psnr(rgb, gt));
    im["ssim"] = ssim_ok ? finite_or_null(ssim(rgb, gt, variant)) : nlohmann::json();
    im["lpips"] = lpips ? finite_or_null(lpips->distance(rgb, gt)) : nlohmann::json();
    if (keep.defined()) {  // the capture's masks: the scores over the pixels that trained too
      im["unmasked_share"] = keep.to(torch::kFloat).mean().item<double>();
      im["psnr_unmasked"] = finite_or_null(psnr(rgb, gt, keep));
      im["ssim_unmasked"] = ssim_ok ? finite_or_null(ssim(rgb, gt, variant, keep)) : nlohmann::json();
    }
    if (look) {
      const auto m = look->map.contiguous();
      im["look_map"] = std::vector<double>(m.data_ptr<double>(), m.data_ptr<double>() + m.numel());
    }
    if (code) {
      im["look_code_norm"] = code->code.norm().item<double>();
      im["look_code_mse"] = {code->fit.mse_before, code->fit.mse_after};
    }
    im["seconds"] = seconds;
    if (aligned) {
      im["aligned_rotation_deg"] = aligned->rotation_deg;
      im["aligned_shift"] = aligned->shift;
    }
    if (has_depth) {
      const auto d = split.depth[i];
      const auto valid = (d > 0) & (split.alpha[i] > kDepthAlphaThreshold);
      const int64_t n_valid = valid.sum().item<int64_t>();
      auto mae = [&](const torch::Tensor& pred) {
        return n_valid ? finite_or_null((pred - d).abs().masked_select(valid).mean().item<double>()) : nlohmann::json();
      };
      im["depth_mae"] = mae(r.depth_mean);
      im["depth_mae_argmax"] = mae(r.depth_argmax);
      im["depth_mae_front"] = mae(r.depth_front);
    }
    images.push_back(im);
  }
  if (bar) bar->finish();

  nlohmann::json m;
  m["split"] = opts.split;
  m["data"] = data_dir;
  m["images"] = images;
  nlohmann::json mean;
  for (const char* key : {"psnr", "ssim", "lpips"}) mean[key] = mean_of(images, key);
  if (split.mask.defined())
    for (const char* key : {"psnr_unmasked", "ssim_unmasked", "unmasked_share"}) mean[key] = mean_of(images, key);
  if (has_depth)
    for (const char* key : {"depth_mae", "depth_mae_argmax", "depth_mae_front"}) mean[key] = mean_of(images, key);
  m["mean"] = mean;
  m["seconds_per_image"] = count ? nlohmann::json(total_seconds / static_cast<double>(count)) : nlohmann::json();
  m["lpips_weights"] = lpips ? nlohmann::json(lpips_path) : nlohmann::json();
  m["ssim_variant"] = name_of(variant);
  const RunLog log = read_run_log(run.log_path());
  m["step"] = log.last_step >= 0 ? nlohmann::json(log.last_step) : nlohmann::json();
  // Wall-clock seconds of training behind these weights (the log's last train record), so that
  // quality can be compared at equal training time.
  m["train_seconds"] = log.elapsed_s >= 0 ? nlohmann::json(log.elapsed_s) : nlohmann::json();
  m["width"] = k.width;
  m["height"] = k.height;
  m["near"] = ds.near;
  m["far"] = ds.far;
  m["error_map_max"] = kErrorMapMax;
  if (model->camera_refine() && model->camera_refine()->refines_focal())
    m["refined_focal_scale"] = model->camera_refine()->focal_scale_value();  // applied to every view's camera
  m["protocol"] = align && fit_look ? "aligned cameras, fitted look"
                  : align           ? "aligned cameras"
                  : fit_look        ? "fitted look"
                                    : "plain";
  if (fit_look)
    m["look_fit"] = {{"what",
                      "NeRF-W's protocol: an affine colour map (3x3 and a bias) per view fitted by least squares on "
                      "the photo's left half with the model frozen; scores on the right half"},
                     {"scored_columns", std::vector<int64_t>{k.width / 2, k.width}}};
  if (fit_look && model->appearance_code())
    m["look_fit"]["appearance_code"] = {
        {"steps", code_opts.steps},
        {"rays", code_opts.rays},
        {"lr", code_opts.lr},
        {"what",
         "the run's appearance code fitted first on the left half (from the photos' mean), the render "
         "taken with it, the colour map fitted on that render"}};
  if (align)
    m["camera_alignment"] = {{"steps", align_opts.steps},
                             {"rays", align_opts.rays},
                             {"lr", align_opts.lr},
                             {"what", "each held-out camera's rigid correction fitted to its photo, model frozen"}};
  write_file_atomic(out_dir + "/metrics.json", m.dump(2) + "\n");
  return m;
}

}  // namespace ablenerf
