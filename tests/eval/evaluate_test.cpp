// `eval` end to end through the library on a tiny scene made here: metrics.json content checked
// against scores recomputed independently from a fresh render, images written, depth error
// masked as documented, and the report self-contained.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <filesystem>
#include <nlohmann/json.hpp>

#include "data/dataset.h"
#include "eval/evaluate.h"
#include "eval/lpips.h"
#include "eval/metrics.h"
#include "eval/renderer.h"
#include "eval/report.h"
#include "eval_fixtures.h"
#include "test_util.h"
#include "util/errors.h"
#include "util/fs.h"
#include "eval/look_fit.h"
#include "util/image_io.h"

using namespace ablenerf;
namespace fs = std::filesystem;

namespace {
constexpr int kSide = 32;  // >= 31 so that LPIPS (AlexNet) can run
constexpr int kTestViews = 3;
}  // namespace

TEST(Evaluate, WritesImagesMetricsAndReport) {
  test::TempDir t;
  const std::string data = t / "scene", run_dir = t / "run";
  test::make_tiny_scene(data, 4, kTestViews, kSide, kSide, /*with_depth=*/true);
  const RunFolder run = test::make_tiny_run(run_dir, data);

  EvalOptions o;
  o.max_images = 2;
  o.progress = false;
  std::vector<std::string> notes;
  o.note = [&](const std::string& s) { notes.push_back(s); };
  const std::string lpips_file = default_lpips_weights_path();  // the copy in assets/ unless overridden
  const bool have_lpips = !lpips_file.empty() && fs::exists(lpips_file);
  o.lpips_weights = have_lpips ? lpips_file : "";
  const auto m = evaluate_run(run, o);

  const std::string dir = run_dir + "/eval/test";
  const auto on_disk = nlohmann::json::parse(read_file(dir + "/metrics.json"));
  EXPECT_EQ(on_disk, m);
  EXPECT_EQ(m["split"], "test");
  EXPECT_EQ(m["step"], 500);                                 // last step in the fixture's log.jsonl
  EXPECT_DOUBLE_EQ(m["train_seconds"].get<double>(), 50.0);  // its elapsed_s: step / 10
  EXPECT_EQ(m["ssim_variant"], "standard");
  ASSERT_EQ(m["images"].size(), 2u);

  // Independent recomputation: same weights, same dataset, a different chunk size.
  LoadOptions lo;
  lo.splits = {"test"};
  const Dataset ds = Dataset::load(data, lo);
  AbleNerf model = load_run_model(run, torch::kCPU);
  double psnr_sum = 0;
  for (int i = 0; i < 2; ++i) {
    const auto& im = m["images"][static_cast<size_t>(i)];
    EXPECT_EQ(im["index"], i);
    EXPECT_NE(im["file"].get<std::string>().find("r_" + std::to_string(i)), std::string::npos);
    for (const char* suffix : {".png", "_gt.png", "_error.png", "_depth.png"}) {
      const std::string f = dir + "/r_" + std::to_string(i) + suffix;
      ASSERT_TRUE(fs::exists(f)) << f;
      EXPECT_EQ(read_png(f).sizes(), (std::vector<int64_t>{kSide, kSide, 3})) << f;
    }
    const RenderResult r = render_image(model, ds.split("test").c2w[i], ds.intrinsics, 2.0, 6.0, 333, {}, torch::kCPU);
    const auto gt = ds.split("test").images[i];
    ASSERT_TRUE(im["psnr"].is_number());
    EXPECT_NEAR(im["psnr"].get<double>(), psnr(r.rgb, gt), 1e-4);
    psnr_sum += im["psnr"].get<double>();
    EXPECT_NEAR(im["ssim"].get<double>(), ssim(r.rgb, gt), 1e-4);
    // The saved render is the 8-bit version of that image.
    EXPECT_LE(
        (read_png(dir + "/r_" + std::to_string(i) + ".png").to(torch::kFloat) / 255 - r.rgb).abs().max().item<double>(),
        0.5 / 255 + 1e-6);
    // Depth error over depth > 0 (top half) and alpha > 0.5 (left half): the top-left quarter.
    const auto pred = r.depth_mean.slice(0, 0, kSide / 2).slice(1, 0, kSide / 2);
    EXPECT_NEAR(im["depth_mae"].get<double>(), (pred - 4.0).abs().mean().item<double>(), 1e-4);
    if (have_lpips) {
      ASSERT_TRUE(im["lpips"].is_number());
      EXPECT_NEAR(im["lpips"].get<double>(), Lpips(lpips_file).distance(r.rgb, gt), 1e-5);
    } else {
      EXPECT_TRUE(im["lpips"].is_null());
    }
    EXPECT_GT(im["seconds"].get<double>(), 0.0);
  }
  EXPECT_NEAR(m["mean"]["psnr"].get<double>(), psnr_sum / 2, 1e-9);
  EXPECT_TRUE(m["mean"]["depth_mae"].is_number());

  write_report(run);
  const std::string html = read_file(run.report_path());
  EXPECT_NE(html.find("<svg"), std::string::npos);
  EXPECT_NE(html.find("<polyline"), std::string::npos);
  // The loss's terms drawn beside it, by name: the fixture logs "fine" and "proposal".
  const auto loss_chart = html.find("Loss and its terms");
  ASSERT_NE(loss_chart, std::string::npos);
  EXPECT_NE(html.find(">proposal<", loss_chart), std::string::npos);
  EXPECT_NE(html.find(">fine<", loss_chart), std::string::npos);
  // PSNR against wall-clock minutes too: the fixture's last record is at 50 s = 0.83 minutes.
  const auto time_chart = html.find("PSNR against training time");
  ASSERT_NE(time_chart, std::string::npos);
  EXPECT_NE(html.find(">minutes<", time_chart), std::string::npos);
  EXPECT_NE(html.find("data:image/png;base64,iVBORw0KGgo"), std::string::npos);  // an embedded PNG
  EXPECT_NE(html.find("model.width"), std::string::npos);                        // config table
  // Self-contained: no scripts, no external images or stylesheets.
  EXPECT_EQ(html.find("<script"), std::string::npos);
  EXPECT_EQ(html.find("src=\"http"), std::string::npos);
  EXPECT_EQ(html.find("<link"), std::string::npos);
}

// NeRF-W's protocol (eval/look_fit.h). The fit itself: a photo that is an exact affine map of the
// render on its left half (its right half anything, a masked-out left pixel anything) gives back that
// map. Then through evaluate_run: test photos made from the run's own renders through a colour map
// score low in the plain protocol and near-exactly (>= 40 dB, the photos' 8-bit rounding) on the
// right halves with the fitted look; metrics.json names the protocol.
TEST(Evaluate, FittedLookIsNerfWsProtocol) {
  const auto map = torch::tensor({0.6, 0.1, 0.0, 0.0, 0.7, 0.0, 0.05, 0.0, 0.5, 0.1, 0.05, 0.2}, torch::kDouble)
                       .reshape({4, 3});  // rows: r, g, b, bias
  const auto through = [&](const torch::Tensor& rgb) {
    const auto flat = rgb.to(torch::kDouble).reshape({-1, 3});
    return (torch::matmul(flat, map.slice(0, 0, 3)) + map[3]).reshape(rgb.sizes()).to(torch::kFloat);
  };
  torch::manual_seed(5);
  const auto render = torch::rand({6, 10, 3});
  auto photo = through(render);
  photo.slice(1, 5).uniform_();  // the right half says nothing
  auto keep = torch::ones({6, 10}, torch::kBool);
  photo[2][1] = torch::tensor({1.0f, 0.0f, 1.0f});  // a corrupted left pixel, masked out
  keep[2][1] = false;
  const LookFit fit = fit_look_left_half(render, photo, keep);
  EXPECT_LT((fit.map - map).abs().max().item<double>(), 1e-6);
  EXPECT_LT((fit.fitted.slice(1, 0, 5) - through(render).slice(1, 0, 5)).abs().max().item<float>(), 1e-6);
  // Flat colours cannot be fitted: the identity.
  const auto flat = fit_look_left_half(torch::full({4, 4, 3}, 0.5f), torch::rand({4, 4, 3}));
  EXPECT_TRUE(
      torch::allclose(flat.map, torch::cat({torch::eye(3, torch::kDouble), torch::zeros({1, 3}, torch::kDouble)})));

  test::TempDir t;
  const std::string data = t / "scene", run_dir = t / "run";
  test::make_tiny_scene(data, 4, kTestViews, kSide, kSide, /*with_depth=*/false);
  const RunFolder run = test::make_tiny_run(run_dir, data);
  EvalOptions o;
  o.progress = false;
  o.note = [](const std::string&) {};
  o.lpips_weights = "";
  evaluate_run(run, o);
  for (int i = 0; i < kTestViews; ++i) {  // the test photos: the renders through the map, opaque
    const auto r = read_png(run_dir + "/eval/test/r_" + std::to_string(i) + ".png").to(torch::kFloat) / 255;
    write_png(data + "/test/r_" + std::to_string(i) + ".png",
              torch::cat({through(r), torch::ones({kSide, kSide, 1})}, -1));
  }
  const auto plain = evaluate_run(run, o);
  EXPECT_EQ(plain["protocol"], "plain");
  EXPECT_LT(plain["mean"]["psnr"].get<double>(), 25.0);
  o.fit_look = true;
  const auto fitted = evaluate_run(run, o);
  EXPECT_EQ(fitted["protocol"], "fitted look");
  EXPECT_TRUE(fitted.contains("look_fit"));
  write_report(run);  // the report says how the views were scored
  EXPECT_NE(read_file(run_dir + "/report.html").find("<td>fitted look</td>"), std::string::npos);
  EXPECT_GE(fitted["mean"]["psnr"].get<double>(), 40.0);
  // (The map itself is ill-conditioned here, the untrained model's colours spanning a narrow range:
  // the exact recovery is the first half's check.)
  EXPECT_EQ(fitted["images"][0]["look_map"].size(), 12u);
}

// NeRF-W's protocol with appearance codes: test photos rendered with a training photo's code are
// matched on their right halves once the code is fitted on the left (the colour map alone, an
// affine map of the mean look's colours, cannot say what the code does through the LE decoder);
// metrics.json names the code fit and each view's fit.
TEST(Evaluate, FittedLookFitsTheRunsAppearanceCode) {
  test::TempDir t;
  const std::string data = t / "scene", run_dir = t / "run";
  test::make_tiny_scene(data, 3, kTestViews, kSide, kSide, /*with_depth=*/false);
  const RunFolder run = test::make_tiny_run(run_dir, data);
  torch::manual_seed(8);
  const auto v = 2.0 * torch::randn({16});  // strong enough to move an untrained model's colours
  test::give_run_appearance_codes(run_dir, torch::stack({torch::zeros_like(v), v, -v}));
  {  // the test photos: each view rendered with photo 1's code (centred: v itself), opaque
    LoadOptions lo;
    lo.splits = {"test"};
    const Dataset ds = Dataset::load(data, lo);
    AbleNerf model = load_run_model(run, torch::kCPU);
    model->eval();
    ForwardOptions look;
    look.appearance = model->appearance_code()->look(1);
    for (int i = 0; i < kTestViews; ++i) {
      const auto r = render_image(model, ds.split("test").c2w[i], ds.intrinsics, 2.0, 6.0, 512, look, torch::kCPU);
      write_png(data + "/test/r_" + std::to_string(i) + ".png",
                torch::cat({r.rgb, torch::ones({kSide, kSide, 1})}, -1));
    }
  }
  EvalOptions o;
  o.progress = false;
  o.note = [](const std::string&) {};
  o.lpips_weights = "";
  const auto plain = evaluate_run(run, o);
  o.fit_look = true;
  const auto fitted = evaluate_run(run, o);
  EXPECT_EQ(fitted["protocol"], "fitted look");
  ASSERT_TRUE(fitted["look_fit"].contains("appearance_code"));
  EXPECT_EQ(fitted["look_fit"]["appearance_code"]["steps"], 100);
  for (const auto& im : fitted["images"]) {
    ASSERT_EQ(im["look_code_mse"].size(), 2u);
    EXPECT_LT(im["look_code_mse"][1].get<double>(), im["look_code_mse"][0].get<double>());
  }
  const double p_plain = plain["mean"]["psnr"].get<double>(), p_fitted = fitted["mean"]["psnr"].get<double>();
  EXPECT_LT(p_plain, 45.0) << "fitted " << p_fitted << " dB";  // the code moves the photos
  EXPECT_GT(p_fitted, p_plain + 5.0) << "plain " << p_plain << " dB";
}

TEST(Evaluate, SmallImagesSkipLpipsAndStandardSsimWithANote) {
  test::TempDir t;
  test::make_tiny_scene(t / "scene", 2, 1, 8, 8, false);
  const RunFolder run = test::make_tiny_run(t / "run", t / "scene");
  EvalOptions o;
  o.progress = false;
  o.lpips_weights = "/definitely/not/used.pt";  // too small for AlexNet: never opened
  std::vector<std::string> notes;
  o.note = [&](const std::string& s) { notes.push_back(s); };
  const auto m = evaluate_run(run, o);
  EXPECT_TRUE(m["images"][0]["lpips"].is_null());
  EXPECT_TRUE(m["images"][0]["ssim"].is_null());
  EXPECT_TRUE(m["mean"]["lpips"].is_null());
  EXPECT_TRUE(m["images"][0]["psnr"].is_number());
  EXPECT_FALSE(m["mean"].contains("depth_mae"));  // no ground-truth depth in this scene
  ASSERT_EQ(notes.size(), 2u);
  EXPECT_NE(notes[0].find("LPIPS skipped"), std::string::npos);
  // The release SSIM variant works on any size.
  o.ssim = "release";
  EXPECT_TRUE(evaluate_run(run, o)["images"][0]["ssim"].is_number());
}

TEST(Evaluate, BadInputsNameTheProblem) {
  test::TempDir t;
  test::make_tiny_scene(t / "scene", 2, 1, 8, 8, false);
  const RunFolder run = test::make_tiny_run(t / "run", t / "scene");
  EvalOptions o;
  o.progress = false;
  o.split = "val";
  try {
    evaluate_run(run, o);
    FAIL() << "expected InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("no split 'val' (available: train, test)"), std::string::npos) << e.what();
  }
  o.split = "test";
  o.ssim = "fancy";
  EXPECT_THROW(evaluate_run(run, o), InputError);
}

TEST(Evaluate, ChunkAndDownscaleMustBePositiveWhenGiven) {
  test::TempDir t;
  test::make_tiny_scene(t / "scene", 2, 1, 8, 8, false);
  const RunFolder run = test::make_tiny_run(t / "run", t / "scene");
  auto refused = [&](const EvalOptions& o, const std::string& field) {
    try {
      evaluate_run(run, o);
    } catch (const InputError& e) {
      EXPECT_EQ(e.file(), field) << e.what();
      EXPECT_NE(std::string(e.what()).find("must be positive"), std::string::npos) << e.what();
      return;
    }
    ADD_FAILURE() << field << " accepted";
  };
  for (const int64_t bad : {int64_t(0), int64_t(-3)}) {
    EvalOptions o;
    o.progress = false;
    o.note = [](const std::string&) {};
    o.chunk = bad;
    refused(o, "--chunk");
    EvalOptions d;
    d.progress = false;
    d.note = [](const std::string&) {};
    d.downscale = static_cast<int>(bad);
    refused(d, "--downscale");
  }
  // Control: the same run evaluates with positive values, and nothing was written by the refusals.
  EXPECT_FALSE(fs::exists(t / "run/eval/test/metrics.json"));
  EvalOptions ok;
  ok.progress = false;
  ok.note = [](const std::string&) {};
  ok.chunk = 7;
  ok.downscale = 1;
  EXPECT_EQ(evaluate_run(run, ok)["images"].size(), 1u);
}
