// The CLI end to end: `info` as the dataset validator, exit codes and one-line errors.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>
#include <string>

#include "test_geometry.h"
#include "test_util.h"
#include "util/fs.h"
#include "util/image_io.h"

using namespace ablenerf;

TEST(Cli, HelpForEverySubcommand) {
  for (const char* sub :
       {"synth", "process", "train", "eval", "render", "view", "bench", "export", "import", "info", "metrics"}) {
    auto r = test::run_cli(std::string(sub) + " --help");
    EXPECT_EQ(r.exit_code, 0) << sub << ": " << r.output;
    EXPECT_NE(r.output.find("Usage"), std::string::npos) << sub;
  }
}

// --version names the release and the LibTorch the binary was built with.
TEST(Cli, VersionNamesTheReleaseAndLibTorch) {
  const auto r = test::run_cli("--version");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(r.output.rfind(std::string("ablenerf ") + ABLENERF_VERSION + " (LibTorch ", 0), 0u) << r.output;
}

// The presets by name are the files of configs/ compiled in: each preset's keys equal its file's;
// a name that is not a preset, or a preset beside --config, is refused with exit code 2, the line
// naming --preset and the presets there are.
TEST(Cli, PresetsByNameAreTheConfigFiles) {
  for (const std::string name : {"capture", "demo", "blender"}) {
    const auto by_name = test::run_cli("info --preset " + name);
    const auto by_file = test::run_cli("info --config " + test::source_dir() + "/configs/" + name + ".toml");
    ASSERT_EQ(by_name.exit_code, 0) << by_name.output;
    ASSERT_EQ(by_file.exit_code, 0) << by_file.output;
    const auto a = nlohmann::json::parse(by_name.output), b = nlohmann::json::parse(by_file.output);
    EXPECT_EQ(a["config"]["keys"], b["config"]["keys"]) << name;
    EXPECT_EQ(a["config"]["source"], "preset " + name);
  }
  const auto unknown = test::run_cli("info --preset nope");
  EXPECT_EQ(unknown.exit_code, 2) << unknown.output;
  EXPECT_NE(unknown.output.find("--preset"), std::string::npos) << unknown.output;
  EXPECT_NE(unknown.output.find("capture"), std::string::npos) << unknown.output;
  const auto both = test::run_cli("info --preset demo --config " + test::source_dir() + "/configs/demo.toml");
  EXPECT_EQ(both.exit_code, 2) << both.output;
}

// One spelling per idea: train's --downscale and --steps are data.downscale and train.steps (the
// run's config.toml holds them); an old spelling (train --view-port, export and metrics --poses)
// still works, with one line naming the new one; without --preset or --config train says in one
// line that it trains the paper's model.
TEST(Cli, TrainFlagsForConfigKeysAndOldSpellings) {
  test::TempDir t;
  ASSERT_EQ(test::run_cli("synth --out " + (t / "data") + " --res 16 --train-views 4 --test-views 1").exit_code, 0);
  const auto r = test::run_cli("train --data " + (t / "data") + " --preset demo --out " + (t / "run") +
                               " --downscale 2 --steps 3 --view-port 7007 --set train.time_budget_s=0");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("--view-port is now --port"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("no --preset or --config"), std::string::npos) << r.output;
  std::ifstream cfg_file(t / "run/config.toml");
  const std::string cfg((std::istreambuf_iterator<char>(cfg_file)), std::istreambuf_iterator<char>());
  EXPECT_NE(cfg.find("downscale = 2"), std::string::npos) << cfg;
  EXPECT_NE(cfg.find("steps = 3"), std::string::npos) << cfg;
  const auto old = test::run_cli("export --run " + (t / "run") + " --poses " + (t / "cameras.json"));
  // A run without camera refinement has no refined cameras: refused as with the new spelling.
  const auto now = test::run_cli("export --run " + (t / "run") + " --cameras " + (t / "cameras.json"));
  EXPECT_EQ(old.exit_code, now.exit_code) << old.output << now.output;
  EXPECT_NE(old.output.find("--poses is now --cameras"), std::string::npos) << old.output;
  EXPECT_EQ(now.output.find("is now"), std::string::npos) << now.output;
  const auto bare = test::run_cli("train --data " + (t / "data") + " --out " + (t / "bare") +
                                  " --steps 1 --set train.rays_per_step=8 --set train.micro_batch=8");
  ASSERT_EQ(bare.exit_code, 0) << bare.output;
  EXPECT_NE(bare.output.find("no --preset or --config: the paper's model"), std::string::npos) << bare.output;
}

// data.downscale = 0: train chooses the size (train/image_size.h) and records it in the run's
// config; info says the same. Six 48x48 views, 4 steps of 96 rays (384 rays, 4 passes: at most 96
// pixels): 1/12 is 4x4 x 6 = 96 pixels, 1/8 would be 216.
TEST(Cli, TrainChoosesTheImageSizeFromTheCapture) {
  test::TempDir t;
  ASSERT_EQ(test::run_cli("synth --out " + (t / "data") + " --res 48 --train-views 6 --test-views 1").exit_code, 0);
  const std::string sets =
      " --set data.downscale=0 --set data.auto_passes=4 --set data.auto_min_side=4 --set train.time_budget_s=0"
      " --set train.rays_per_step=96 --set train.micro_batch=96 --set train.steps=4";
  const auto info = test::run_cli("info --data " + (t / "data") + " --preset demo" + sets);
  ASSERT_EQ(info.exit_code, 0) << info.output;
  const auto j = nlohmann::json::parse(info.output.substr(info.output.find('{')));
  EXPECT_NE(j["image_size"].get<std::string>().find("data.downscale = 12 (auto): 6 training photos at 4x4"),
            std::string::npos)
      << info.output;
  EXPECT_EQ(j["dataset"]["width"], 4);
  const auto r = test::run_cli("train --data " + (t / "data") + " --preset demo --out " + (t / "run") + sets);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("data.downscale = 12 (auto)"), std::string::npos) << r.output;
  std::ifstream cfg_file(t / "run/config.toml");
  const std::string cfg((std::istreambuf_iterator<char>(cfg_file)), std::istreambuf_iterator<char>());
  EXPECT_NE(cfg.find("downscale = 12"), std::string::npos) << cfg;
  const auto e = test::run_cli("eval --run " + (t / "run") + " --json");
  ASSERT_EQ(e.exit_code, 0) << e.output;
  // Resumed with more steps (which alone would choose 1/4), the run keeps its size.
  const auto more = test::run_cli("train --data " + (t / "data") + " --preset demo --out " + (t / "run") + sets +
                                  " --set train.steps=40 --set train.ckpt_every=1000 --resume");
  ASSERT_EQ(more.exit_code, 0) << more.output;
  EXPECT_EQ(more.output.find("(auto)"), std::string::npos) << more.output;
  std::ifstream again_file(t / "run/config.toml");
  const std::string again((std::istreambuf_iterator<char>(again_file)), std::istreambuf_iterator<char>());
  EXPECT_NE(again.find("downscale = 12"), std::string::npos) << again;
  const auto fresh = test::run_cli("info --data " + (t / "data") + " --preset demo" + sets + " --set train.steps=40");
  EXPECT_NE(fresh.output.find("data.downscale = 4 (auto)"), std::string::npos) << fresh.output;
}

TEST(Cli, InfoOnLego) {
  const std::string lego = test::lego_dir();
  if (lego.empty()) GTEST_SKIP() << "lego not present";
  auto r = test::run_cli("info --data " + lego + " --set data.downscale=8");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  auto j = nlohmann::json::parse(r.output.substr(r.output.find('{')));
  EXPECT_EQ(j["dataset"]["splits"]["train"]["count"], 100);
  EXPECT_EQ(j["dataset"]["splits"]["test"]["count"], 200);
  EXPECT_EQ(j["dataset"]["width"], 100);
}

TEST(Cli, BadInputExitsTwoWithOneLine) {
  test::TempDir t;
  test::write_file(t / "transforms_train.json", "{ not json");
  auto r = test::run_cli("info --data " + t.path());
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("transforms_train.json"), std::string::npos) << r.output;
  // exactly one line of output
  EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << r.output;
  auto r2 = test::run_cli("info --data /nonexistent/dir");
  EXPECT_EQ(r2.exit_code, 2);
  auto r3 = test::run_cli("info --config /nonexistent.toml");
  EXPECT_EQ(r3.exit_code, 2);
  EXPECT_NE(r3.output.find("/nonexistent.toml"), std::string::npos) << r3.output;
  auto r4 = test::run_cli("info --set model.no_such_key=3");
  EXPECT_EQ(r4.exit_code, 2);
  EXPECT_NE(r4.output.find("model.no_such_key"), std::string::npos) << r4.output;
}

// `info` says where the cameras are: seven cameras 4 units from the origin on an arc from azimuth
// 20 to 110 degrees, at elevations 10 and 40 degrees in turn, cover 90 degrees of azimuth.
TEST(Cli, InfoReportsTheCamerasCoverage) {
  test::TempDir t;
  std::ostringstream js;
  js.precision(17);
  std::filesystem::create_directories(t / "train");
  js << "{\"camera_angle_x\": 0.7, \"frames\": [";
  for (int i = 0; i < 7; ++i) {
    const double az = (20.0 + 15.0 * i) * M_PI / 180, el = (i % 2 ? 40.0 : 10.0) * M_PI / 180;
    const test::V3 eye{4 * std::cos(el) * std::cos(az), 4 * std::cos(el) * std::sin(az), 4 * std::sin(el)};
    const test::Frame3 f = test::look_at(eye, {0, 0, 0}, {0, 0, 1});
    js << (i ? "," : "") << "{\"file_path\": \"./train/r_" << i << "\", \"transform_matrix\": [";
    for (size_t r = 0; r < 3; ++r)
      js << "[" << f.right[r] << "," << f.up[r] << "," << f.back[r] << "," << f.eye[r] << "],";
    js << "[0,0,0,1]]}";
    write_png(t / ("train/r_" + std::to_string(i) + ".png"), torch::full({4, 4, 4}, 0.5f));
  }
  js << "]}";
  test::write_file(t / "transforms_train.json", js.str());
  auto r = test::run_cli("info --data " + t.path());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto cov = nlohmann::json::parse(r.output.substr(r.output.find('{')))["dataset"]["coverage"];
  EXPECT_NEAR(cov["azimuth_deg"].get<double>(), 90.0, 1e-3);
  EXPECT_NEAR(cov["elevation_min_deg"].get<double>(), 10.0, 1e-3);
  EXPECT_NEAR(cov["elevation_max_deg"].get<double>(), 40.0, 1e-3);
  EXPECT_NEAR(cov["mean_distance"].get<double>(), 4.0, 1e-4);
}

// --quiet and --verbose on every command set how much of the log (util/log.h) reaches the terminal:
// the loader's debug line only with --verbose, the training progress and notes not at all with
// --quiet (the command's result on standard output stays).
TEST(Cli, QuietAndVerboseSetHowMuchOfTheLogShows) {
  test::TempDir t;
  ASSERT_EQ(test::run_cli("synth --out " + t / "d" + " --res 8 --train-views 3 --test-views 1").exit_code, 0);
  const auto plain = test::run_cli("info --data " + t / "d");
  const auto verbose = test::run_cli("info --data " + t / "d" + " --verbose");
  ASSERT_EQ(plain.exit_code, 0) << plain.output;
  ASSERT_EQ(verbose.exit_code, 0) << verbose.output;
  EXPECT_EQ(plain.output.find("load: "), std::string::npos) << plain.output;
  EXPECT_NE(verbose.output.find("load: "), std::string::npos) << verbose.output;
  const std::string train =
      "train --data " + t / "d" + " --config " + test::source_dir() +
      "/configs/demo.toml --set train.steps=3 --set train.eval_every=0 --set train.log_every=1 --out ";
  const auto loud = test::run_cli(train + t / "r1");
  const auto quiet = test::run_cli(train + t / "r2 --quiet");
  ASSERT_EQ(loud.exit_code, 0) << loud.output;
  ASSERT_EQ(quiet.exit_code, 0) << quiet.output;
  EXPECT_NE(loud.output.find("train 3/3"), std::string::npos) << loud.output;
  EXPECT_EQ(quiet.output.find("train 3/3"), std::string::npos) << quiet.output;
  // Quiet: only the command's result: the run folder it wrote and the four next commands.
  EXPECT_EQ(std::count(quiet.output.begin(), quiet.output.end(), '\n'), 6) << quiet.output;
  EXPECT_NE(quiet.output.find("run written to"), std::string::npos) << quiet.output;
  // The next commands, each on the run just written.
  for (const char* next :
       {"ablenerf eval --run ", "ablenerf render --run ", "ablenerf export --run ", "ablenerf view --run "})
    EXPECT_NE(quiet.output.find(next), std::string::npos) << next << "\n" << quiet.output;
}

// --json on every command that reports: with --quiet the whole output is one JSON object holding
// what the text report says (synth, train, eval and render report text otherwise; info, metrics,
// export, import, process and bench report JSON either way and accept the flag).
TEST(Cli, JsonGivesOneObjectFromEveryReportingCommand) {
  test::TempDir t;
  const auto one_object = [](const test::CommandResult& r) {
    EXPECT_EQ(r.exit_code, 0) << r.output;
    EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << r.output;
    return nlohmann::json::parse(r.output);
  };
  const auto synth =
      one_object(test::run_cli("synth --quiet --json --out " + t / "d" + " --res 8 --train-views 3 --test-views 2"));
  EXPECT_EQ(synth["out"], t / "d");
  EXPECT_EQ(synth["train_views"], 3);
  EXPECT_EQ(synth["test_views"], 2);
  const auto train = one_object(test::run_cli("train --quiet --json --data " + t / "d" + " --config " +
                                              test::source_dir() + "/configs/demo.toml --steps 2 --out " + t / "r"));
  EXPECT_EQ(train["run"], t / "r");
  ASSERT_EQ(train["next"].size(), 4u);
  EXPECT_EQ(train["next"][0], "ablenerf eval --run " + t / "r");
  const auto eval = one_object(test::run_cli("eval --quiet --json --run " + t / "r"));
  EXPECT_EQ(eval["views"], 2);
  EXPECT_TRUE(eval["mean"]["psnr"].is_number());
  // The same figures as the metrics file it names.
  const auto metrics = nlohmann::json::parse(read_file(eval["metrics"].get<std::string>()));
  EXPECT_DOUBLE_EQ(eval["mean"]["psnr"].get<double>(), metrics["mean"]["psnr"].get<double>());
  const auto render = one_object(test::run_cli("render --quiet --json --run " + t / "r" +
                                               " --path orbit --frames 2 --width 8 --height 6 --out " + t / "frames"));
  EXPECT_EQ(render["frames"], 2);
  EXPECT_EQ(render["width"], 8);
  const auto info = test::run_cli("info --quiet --json --data " + t / "d");  // JSON either way (indented)
  ASSERT_EQ(info.exit_code, 0) << info.output;
  EXPECT_TRUE(nlohmann::json::parse(info.output).is_object());
  // Without --json the text reports stay.
  const auto text = test::run_cli("eval --quiet --run " + t / "r");
  EXPECT_NE(text.output.find("PSNR"), std::string::npos) << text.output;
  EXPECT_THROW(nlohmann::json::parse(text.output), nlohmann::json::exception);
}

// On a CPU with AVX2 and FMA, `ablenerf` never runs OpenBLAS's Prescott (SSE3) kernels, which
// Debian's OpenBLAS 0.3.21 falls back to on CPUs it does not know (kernels/cpu_parallel.h,
// blas_core_override): started without OPENBLAS_CORETYPE, `bench` reports the kernels in use.
TEST(Cli, BenchRunsBlasKernelsForTheCpusVectorUnits) {
#if defined(__x86_64__)
  __builtin_cpu_init();
  if (!__builtin_cpu_supports("avx2") || !__builtin_cpu_supports("fma")) GTEST_SKIP() << "no AVX2/FMA on this CPU";
  const char* given = std::getenv("OPENBLAS_CORETYPE");
  const std::string saved = given ? given : "";
  unsetenv("OPENBLAS_CORETYPE");
  auto r = test::run_cli("bench --config " + test::source_dir() +
                         "/configs/demo.toml --rays 8 --steps 1 --warmup 0 --matmul 32 --image 8");
  if (given) setenv("OPENBLAS_CORETYPE", saved.c_str(), 1);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto j = nlohmann::json::parse(r.output.substr(r.output.find('{')));
  const std::string core = j["openblas_core"].get<std::string>();
  if (core.empty()) GTEST_SKIP() << "BLAS without OpenBLAS's runtime dispatch";
  EXPECT_NE(core, "Prescott");
  // Either OpenBLAS knew the CPU, or the program restarted itself with a type for it.
  if (!j["openblas_coretype"].is_null()) {
    const std::string type = j["openblas_coretype"].get<std::string>();
    EXPECT_TRUE(type == "Haswell" || type == "SkylakeX") << type;
  }
#else
  GTEST_SKIP() << "x86-64 only";
#endif
}

// ABLENERF_CPU_ISA caps the project's CPU kernels as a CPU without AVX-512 or AMX would run them,
// on any CPU: under "baseline" `bench` reports the scalar forms and no bfloat16 products,
// compute.precision = "bf16" is refused naming the key (exit 2), and training runs the scalar forms
// to nearly the same model as the widest forms this CPU has (their roundings apart). A value not in
// the list is refused naming the variable.
TEST(Cli, CpuIsaCapRunsTheBaselineForms) {
  test::TempDir t;
  ASSERT_EQ(test::run_cli("synth --quiet --out " + t / "d" + " --res 8 --train-views 3 --test-views 2").exit_code, 0);
  const std::string demo = " --config " + test::source_dir() + "/configs/demo.toml";
  const std::string train = "train --quiet --data " + t / "d" + demo + " --steps 3 --set compute.precision=fp32";
  test::CommandResult bench, bf16, capped, unknown;
  {
    const test::ScopedEnv cap("ABLENERF_CPU_ISA", "baseline");
    bench = test::run_cli("bench" + demo + " --rays 8 --steps 1 --warmup 0 --matmul 32 --image 8");
    bf16 = test::run_cli("train --quiet --data " + t / "d" + demo + " --steps 1 --set compute.precision=bf16 --out " +
                         t / "bf16");
    capped = test::run_cli(train + " --out " + t / "capped");
  }
  {
    const test::ScopedEnv cap("ABLENERF_CPU_ISA", "sse9");
    unknown = test::run_cli("info --data " + t / "d");
  }
  const auto widest = test::run_cli(train + " --out " + t / "widest");
  ASSERT_EQ(bench.exit_code, 0) << bench.output;
  const auto j = nlohmann::json::parse(bench.output.substr(bench.output.find('{')));
  EXPECT_EQ(j["cpu_kernels"], "baseline");
  EXPECT_EQ(j["cpu_bf16_products"], false);
  EXPECT_EQ(bf16.exit_code, 2) << bf16.output;
  EXPECT_NE(bf16.output.find("compute.precision"), std::string::npos) << bf16.output;
  EXPECT_EQ(unknown.exit_code, 2) << unknown.output;
  EXPECT_NE(unknown.output.find("ABLENERF_CPU_ISA"), std::string::npos) << unknown.output;
  EXPECT_EQ(std::count(unknown.output.begin(), unknown.output.end(), '\n'), 1) << unknown.output;
  ASSERT_EQ(capped.exit_code, 0) << capped.output;
  ASSERT_EQ(widest.exit_code, 0) << widest.output;
  // The same three steps: the held-out PSNR within rounding of each other.
  const auto psnr = [&](const std::string& run) {
    const auto r = test::run_cli("eval --quiet --json --run " + t / run);
    EXPECT_EQ(r.exit_code, 0) << r.output;
    return nlohmann::json::parse(r.output)["mean"]["psnr"].get<double>();
  };
  EXPECT_NEAR(psnr("capped"), psnr("widest"), 0.05);
}
