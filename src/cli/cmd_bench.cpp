// `ablenerf bench`: training and rendering throughput, achieved FLOP/s against the device's
// measured sgemm peak, and peak memory, printed as one JSON object (measuring code: train/bench.h).
#include <filesystem>
#include <iostream>

#include "cli/command.h"
#include "cli/common.h"
#include "train/bench.h"
#include "util/errors.h"
#include "util/fs.h"
#include "train/train_config.h"
#include "data/data_config.h"
#include "model/compute_config.h"

namespace ablenerf::cli {
namespace cmd_bench {

namespace fs = std::filesystem;
constexpr size_t kTraceTopOps = 15;

struct BenchArgs {
  ConfigOptions cfg;
  std::string device = "cpu";
  int64_t rays = 64, micro_batch = 0, render_rays = 0, steps = 5, warmup = 1, matmul = 2048, image = 800;
  int threads = 0;
  bool compare = false;
  std::string trace;
};

void setup(CLI::App& app) {
  auto a = std::make_shared<BenchArgs>();
  a->cfg.add_to(app, false);
  app.add_option("--device", a->device, "cpu | cuda | cuda:N | auto")->capture_default_str();
  app.add_option("--rays", a->rays, "Rays per training step")->capture_default_str();
  app.add_option("--micro-batch", a->micro_batch, "Rays per forward/backward within a step (0 = --rays)")
      ->capture_default_str();
  app.add_option("--render-rays", a->render_rays, "Rays per rendering forward (0 = --rays)")->capture_default_str();
  app.add_option("--steps", a->steps, "Timed repetitions (median reported)")->capture_default_str();
  app.add_option("--warmup", a->warmup, "Untimed repetitions first")->capture_default_str();
  app.add_option("--matmul", a->matmul, "n of the n^3 sgemm measuring the peak")->capture_default_str();
  app.add_option("--image", a->image, "Side of the square image for seconds/image")->capture_default_str();
  app.add_option("--threads", a->threads, "Intra-op CPU threads (0 = LibTorch default)")->capture_default_str();
  app.add_option("--trace", a->trace,
                 "After the timed steps, run --steps more under LibTorch's profiler: write their operator trace "
                 "(Chrome trace JSON, for Perfetto) to this file and add the ops of largest self time and the time of "
                 "each of the model's stages to the report; on a CPU also --steps rendering forwards, their trace "
                 "beside it as NAME.render.json");
  app.add_flag("--compare", a->compare,
               "Also measure the same model with every fast path off (compute.precision=fp32, "
               "compute.attention=plain, compute.cpu_split=ops, train.graph=false) in this run, and report the ratios");
  add_json_flag(app);
  app.callback([a] {
    const Config c = resolve_config(a->cfg);
    if (a->rays < 1) throw InputError("bench", "--rays", "must be >= 1");
    if (a->micro_batch < 0) throw InputError("bench", "--micro-batch", "must be >= 0");
    if (a->render_rays < 0) throw InputError("bench", "--render-rays", "must be >= 0");
    if (a->steps < 1) throw InputError("bench", "--steps", "must be >= 1");
    if (a->warmup < 0) throw InputError("bench", "--warmup", "must be >= 0");
    if (a->matmul < 1) throw InputError("bench", "--matmul", "must be >= 1");
    if (a->image < 1) throw InputError("bench", "--image", "must be >= 1");
    if (a->threads < 0) throw InputError("bench", "--threads", "must be >= 0");
    if (a->threads > 0) torch::set_num_threads(a->threads);
    BenchOptions o;
    o.device = parse_device(a->device);
    o.train_rays = a->rays;
    o.render_rays = a->render_rays;
    o.micro_batch = a->micro_batch;
    o.steps = a->steps;
    o.warmup = a->warmup;
    o.matmul_size = a->matmul;
    o.image_side = a->image;
    o.near = c.get<DataConfig>().near;
    o.far = c.get<DataConfig>().far;
    if (!a->trace.empty()) {
      if (a->compare) throw InputError("bench", "--trace", "cannot be combined with --compare");
      const auto dir = fs::absolute(a->trace).parent_path();
      if (!fs::is_directory(dir)) throw InputError(a->trace, "--trace", "folder " + dir.string() + " does not exist");
      o.trace_steps = a->steps;
    }
    if (!a->compare) {
      const BenchMeasurements m = measure(c, o);
      auto report = bench_report(c, o, m);
      if (!a->trace.empty()) {
        write_file_atomic(a->trace, m.trace_json);
        report["trace"] = trace_summary(m.trace_json, o.trace_steps, kTraceTopOps);
        report["trace"]["file"] = a->trace;
        report["trace"]["note"] =
            report["trace"].contains("gpu")
                ? "profiled steps, run after the timed ones (Kineto): host ops by self time, and under \"gpu\" "
                  "the device's kernels, copies and fills by their GPU time"
                : "profiled steps, run after the timed ones; the calling thread's ops only (with the CPU ray split: "
                  "the first slice's forward/backward and the rest of the step)";
        if (!m.render_trace_json.empty()) {
          const fs::path file(a->trace);
          const auto render_file = file.parent_path() / (file.stem().string() + ".render" + file.extension().string());
          write_file_atomic(render_file.string(), m.render_trace_json);
          report["trace"]["render"] = trace_summary(m.render_trace_json, o.trace_steps, kTraceTopOps);
          report["trace"]["render"]["file"] = render_file.string();
          report["trace"]["render"]["note"] =
              "profiled rendering forwards (one chunk each), run after the timed ones; the calling thread's ops only";
        }
      }
      std::cout << report.dump(2) << std::endl;
      return;
    }
    Config base = c;
    base.get<ComputeConfig>().precision = Precision::Fp32;
    base.get<ComputeConfig>().attention = AttentionKernel::Plain;
    base.get<ComputeConfig>().cpu_split = CpuSplit::Ops;
    base.get<TrainConfig>().graph = false;
    const auto reference = bench_report(base, o, measure(base, o));
    const auto fast = bench_report(c, o, measure(c, o));
    const auto ratio = [&](const char* what) {
      return fast[what]["rays_per_s"].get<double>() / reference[what]["rays_per_s"].get<double>();
    };
    nlohmann::json j{{"fast", fast},
                     {"reference", reference},
                     {"speedup", {{"train", ratio("train")}, {"render", ratio("render")}}},
                     {"speedup_note",
                      "rays/s of the config's compute settings over fp32 + plain attention + cpu_split=ops + no CUDA "
                      "graph, same run"}};
    std::cout << j.dump(2) << std::endl;
  });
}

}  // namespace cmd_bench
ABLENERF_COMMAND("bench", 50, "Measure training and rendering speed", cmd_bench::setup);
}  // namespace ablenerf::cli
