#include "train/bench.h"

#include <sys/resource.h>
#include <torch/cuda.h>
#include <torch/csrc/autograd/profiler_legacy.h>
#include <torch/version.h>

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <stdexcept>

#include "eval/camera_path.h"
#include "model/able_nerf.h"
#include "model/compute.h"
#include "model/ipe.h"
#include "model/view_encoding.h"
#include "train/trainer.h"
#include "util/fs.h"

// Device-side peak memory needs the CUDA caching allocator, which only CUDA builds of LibTorch
// link; build with -DABLENERF_WITH_CUDA against such a LibTorch (>= 2) to report it.
#if defined(ABLENERF_WITH_CUDA) && TORCH_VERSION_MAJOR >= 2
#include <c10/cuda/CUDACachingAllocator.h>
#define ABLENERF_CUDA_MEMORY_STATS 1
// On CUDA, `--trace` records the GPU's kernels too, through LibTorch's Kineto profiler (CUPTI).
#include <torch/csrc/autograd/profiler_kineto.h>
#define ABLENERF_KINETO_TRACE 1
#endif

namespace ablenerf {

namespace {

constexpr double kFlopPerMac = 2.0;
constexpr size_t kMaxOpName = 200;  // kernel names are whole template signatures
// The backward of a product whose two operands both need gradients is two products of the same
// size (one per operand); a product with one constant operand (input features, no-grad probes)
// needs only the other operand's gradient.
constexpr double kBackwardBothOperands = 2.0;
constexpr double kBackwardOneOperand = 1.0;
constexpr int64_t kRgb = kRgbChannels;
constexpr int64_t kQkv = 3, kKv = 2;
constexpr int64_t kVolumeEmbeddingHiddenLayers = 3;  // 4 Linear layers: in->E, then 3 x E->E
constexpr double kCameraDistance = 4.0;
constexpr double kDirectionJitter = 0.1;
// The in-memory training split of the benchmark: a few Blender-like views (800x800, focal of
// lego's 0.6911 rad field of view), random colours.
constexpr int64_t kBenchViews = 4;
constexpr double kBlenderFocal = 1111.111;
constexpr int64_t kBytesPerKiB = 1024;

// Accumulates products with their backward multiplier.
struct Tally {
  FlopCount c;
  // m x k times k x n.
  void product(double m, double k, double n, double backward_factor) {
    const double f = kFlopPerMac * m * k * n;
    c.forward += f;
    c.backward += backward_factor * f;
  }
};

// One post-norm transformer block per ray: lq queries attending to lk keys. `q_per_ray` is
// false when the queries are shared by the whole batch (the LE cross-attention), so their
// projection is a per-call cost, not a per-ray one.
void transformer_block(Tally& t, double lq, double lk, double e, double ff, bool self, bool q_per_ray) {
  if (self) {
    t.product(lq, e, kQkv * e, kBackwardBothOperands);  // packed Q/K/V
  } else {
    if (q_per_ray) t.product(lq, e, e, kBackwardBothOperands);
    t.product(lk, e, kKv * e, kBackwardBothOperands);  // packed K/V
  }
  // Scores and weighted values, summed over heads (heads x dh = E).
  t.product(lq, e, lk, kBackwardBothOperands);
  t.product(lq, lk, e, kBackwardBothOperands);
  t.product(lq, e, e, kBackwardBothOperands);   // output projection
  t.product(lq, e, ff, kBackwardBothOperands);  // feed-forward in
  t.product(lq, ff, e, kBackwardBothOperands);  // feed-forward out
}

// The volume-embedding MLP of one pass; its input (the IPE features) needs no gradient.
void volume_embedding(Tally& t, const ModelConfig& c) {
  const double e = c.width, s = c.samples;
  t.product(s, static_cast<double>(ipe_width(c.ipe_degrees)), e, kBackwardOneOperand);
  for (int64_t i = 0; i < kVolumeEmbeddingHiddenLayers; ++i) t.product(s, e, e, kBackwardBothOperands);
}

void le_branch(Tally& t, const ModelConfig& c) {
  const double e = c.width, ff = double(c.width) * c.ff_ratio, s = c.samples, n = c.le_count;
  const double view = static_cast<double>(view_encoding_width(c.view_encoding));
  transformer_block(t, n, s, e, ff, /*self=*/false, /*q_per_ray=*/false);  // LE x volumes
  for (int64_t j = 0; j < c.le_layers; ++j) transformer_block(t, n, n, e, ff, true, true);
  transformer_block(t, 1, n, e, ff, /*self=*/false, /*q_per_ray=*/true);  // view decodes LE
  t.product(1, e + view, e, kBackwardBothOperands);                       // LE colour head hidden layer
  t.product(1, e, kRgb, kBackwardBothOperands);                           // LE colour head output
}

}  // namespace

FlopCount model_flops_per_ray(const ModelConfig& c) {
  Tally t;
  const double e = c.width, ff = double(c.width) * c.ff_ratio, tokens = double(c.samples) + 1;
  const bool le = c.le_count > 0;
  if (le) {
    // View token, shared by both passes; its input (the view encoding) needs no gradient.
    t.product(1, static_cast<double>(view_encoding_width(c.view_encoding)), e, kBackwardOneOperand);
  }
  for (const int layers : {c.coarse_layers, c.fine_layers}) {
    volume_embedding(t, c);
    // AB transformer over the ray token plus S volume tokens (the full score matrix is
    // computed: the causal mask is added, not skipped).
    for (int i = 0; i < layers; ++i) transformer_block(t, tokens, tokens, e, ff, true, true);
    // Resampling probe: the ray token's query against every key, without gradient.
    t.product(1, e, tokens, 0.0);
    t.product(1, e, kRgb, kBackwardBothOperands);  // ray colour head
    if (le) le_branch(t, c);
  }
  return t.c;
}

double median(std::vector<double> v) {
  if (v.empty()) throw std::invalid_argument("median of an empty list");
  std::sort(v.begin(), v.end());
  const size_t h = v.size() / 2;
  return v.size() % 2 ? v[h] : 0.5 * (v[h - 1] + v[h]);
}

double Timing::wall_median() const { return median(wall_s); }
double Timing::cpu_median() const { return median(cpu_s); }

namespace {

double process_cpu_seconds() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  const auto sec = [](const timeval& t) { return double(t.tv_sec) + 1e-6 * double(t.tv_usec); };
  return sec(u.ru_utime) + sec(u.ru_stime);
}

int64_t peak_rss_bytes() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return int64_t{u.ru_maxrss} * kBytesPerKiB;  // Linux reports KiB
}

void sync(const torch::Device& d) {
  if (d.is_cuda()) torch::cuda::synchronize(d.index());
}

// Warm-up, then `reps` timed calls of fn; device work is synchronised before each clock read.
template <class Fn>
Timing time_it(const torch::Device& d, int64_t warmup, int64_t reps, Fn&& fn) {
  for (int64_t i = 0; i < warmup; ++i) fn();
  sync(d);
  Timing t;
  for (int64_t i = 0; i < reps; ++i) {
    const auto w0 = std::chrono::steady_clock::now();
    const double c0 = process_cpu_seconds();
    fn();
    sync(d);
    t.cpu_s.push_back(process_cpu_seconds() - c0);
    t.wall_s.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - w0).count());
  }
  return t;
}

// Blender-like training views: cameras on a radius-4 shell looking at the origin.
Split bench_split(int64_t side, uint64_t seed) {
  auto gen = at::detail::createCPUGenerator(seed);
  Split s;
  s.name = "train";
  std::vector<torch::Tensor> poses;
  for (int64_t i = 0; i < kBenchViews; ++i) {
    auto eye =
        torch::nn::functional::normalize(torch::randn({3}, gen), torch::nn::functional::NormalizeFuncOptions().dim(0));
    poses.push_back(look_at(eye * kCameraDistance, torch::zeros({3}), torch::tensor({0.0f, 1.0f, 0.0f})));
  }
  s.c2w = torch::stack(poses);
  s.images = torch::rand({kBenchViews, side, side, kRgb}, gen);
  return s;
}

Intrinsics bench_intrinsics(int64_t side) {
  Intrinsics k;
  k.width = k.height = static_cast<int>(side);
  k.fx = k.fy = kBlenderFocal * static_cast<double>(side) / 800.0;
  k.cx = k.cy = 0.5 * static_cast<double>(side);
  return k;
}

// Blender-like rays for the inference timing: cameras on a radius-4 shell looking roughly at
// the origin, with the footprint of a pixel of an 800x800 Blender view.
Rays bench_rays(int64_t n, uint64_t seed, const torch::Device& d) {
  auto gen = at::detail::createCPUGenerator(seed);
  const auto o = torch::nn::functional::normalize(torch::randn({n, 3}, gen)) * kCameraDistance;
  const auto dir = -o / kCameraDistance + kDirectionJitter * torch::randn({n, 3}, gen);
  const auto radius = static_cast<float>(pixel_radius(bench_intrinsics(800)));
  return {o.to(d), dir.to(d), torch::full({n, 1}, radius).to(d)};
}

}  // namespace

namespace {

// `steps` more training steps under LibTorch's profiler, as Chrome trace JSON. On CUDA with
// LibTorch >= 2: Kineto, the host's ops and the GPU's kernels, memcpys and memsets (CUPTI); so the
// trace says where device time goes inside a CUDA graph's replay as well. Otherwise the legacy
// profiler: the calling thread's ops.
std::string trace_steps(Trainer& trainer, int64_t steps, const torch::Device& device) {
#ifdef ABLENERF_KINETO_TRACE
  if (device.is_cuda()) {
    namespace prof = torch::profiler::impl;
    namespace ap = torch::autograd::profiler;
    const prof::ProfilerConfig config(prof::ProfilerState::KINETO);
    const std::set<prof::ActivityType> activities{prof::ActivityType::CPU, prof::ActivityType::CUDA};
    ap::prepareProfiler(config, activities);
    ap::enableProfiler(config, activities);
    for (int64_t i = 0; i < steps; ++i) trainer.step();
    trainer.flush();
    torch::cuda::synchronize();
    const auto result = ap::disableProfiler();
    const auto file =
        std::filesystem::temp_directory_path() / ("ablenerf_trace_" + std::to_string(::getpid()) + ".json");
    result->save(file.string());
    std::string json = read_file(file.string());
    std::filesystem::remove(file);
    return json;
  }
#endif
  (void)device;
  std::ostringstream trace;
  {
    torch::autograd::profiler::RecordProfile record(trace);
    for (int64_t i = 0; i < steps; ++i) trainer.step();
    trainer.flush();
  }
  return trace.str();
}

}  // namespace

BenchMeasurements measure(const Config& cfg, const BenchOptions& o) {
  BenchMeasurements m;
  m.threads = at::get_num_threads();
  const auto& d = o.device;
  const int64_t render_rays = o.render_rays > 0 ? o.render_rays : o.train_rays;
  const Precision precision = cfg.compute.precision;
  // The trainer's own step (Trainer::step) on an in-memory split: the same rays, micro-batches,
  // loss, optimiser and (on CUDA) CUDA graph as `ablenerf train`.
  Config c = cfg;
  c.train.rays_per_step = o.train_rays;
  c.train.micro_batch = o.micro_batch > 0 ? std::min(o.micro_batch, o.train_rays) : o.train_rays;
  c.train.seed = static_cast<int64_t>(o.seed);
  c.train.time_budget_s = 0;
  TrainOptions to;
  to.device = d;
  to.quiet = true;
  Trainer trainer(c, to);
  trainer.setup(bench_split(o.image_side, o.seed), bench_intrinsics(o.image_side));
  AbleNerf& model = trainer.model();
  m.parameters = model->parameter_count();
#ifdef ABLENERF_CUDA_MEMORY_STATS
  // After the first allocations: the caching allocator of a device exists only from then on.
  if (d.is_cuda()) c10::cuda::CUDACachingAllocator::resetPeakStats(d.index() < 0 ? 0 : d.index());
#endif
  m.device_step = trainer.device_form();
  // Untimed steps first; with a CUDA graph, until it is captured (the capture itself is not timed).
  for (int64_t i = 0; i < o.warmup || (m.device_step && c.train.graph && !trainer.graph_captured()); ++i)
    trainer.step();
  m.graph = trainer.graph_captured();
  m.train = time_it(d, 0, o.steps, [&] { trainer.step(); });
  trainer.flush();
  if (o.trace_steps > 0) m.trace_json = trace_steps(trainer, o.trace_steps, d);
  {
    const auto rays = bench_rays(render_rays, o.seed + 1, d);
    model->eval();
    m.render = time_it(d, o.warmup, o.steps, [&] {
      torch::InferenceMode guard;
      ForwardOptions fo;
      fo.coarse_colour = false;  // as the renderer: an image needs only the fine colour
      const auto out = model->forward(rays, o.near, o.far, fo);
      (void)out;
    });
  }
  {
    // The peak in the precision the model's products run in.
    const auto opts =
        torch::TensorOptions().device(d).dtype(precision == Precision::Bf16 ? torch::kBFloat16 : torch::kFloat);
    m.matmul_dtype = precision == Precision::Bf16 ? "bf16" : "fp32";
    const auto a = torch::randn({o.matmul_size, o.matmul_size}, opts);
    const auto b = torch::randn({o.matmul_size, o.matmul_size}, opts);
    auto c = torch::empty({o.matmul_size, o.matmul_size}, opts);
    m.matmul = time_it(d, 1, o.matmul_reps, [&] { torch::mm_out(c, a, b); });
  }

#ifdef ABLENERF_CUDA_MEMORY_STATS
  if (d.is_cuda()) {
    const auto stats = c10::cuda::CUDACachingAllocator::getDeviceStats(d.index() < 0 ? 0 : d.index());
    m.peak_memory_bytes = stats.allocated_bytes[0].peak;  // aggregate pool
    m.peak_memory_source = "CUDA caching allocator peak allocated bytes";
  }
#endif
  if (m.peak_memory_source.empty()) {
    m.peak_memory_bytes = peak_rss_bytes();
    m.peak_memory_source = d.is_cuda() ? "host getrusage ru_maxrss (device statistics not compiled in)"
                                       : "getrusage ru_maxrss (process peak resident set)";
  }
  return m;
}

namespace {

nlohmann::json timing_json(const Timing& t, double rays, double flops_per_ray, double peak_flops) {
  nlohmann::json j;
  const double wall = t.wall_median(), cpu = t.cpu_median();
  const double rays_per_s = rays / wall;
  j["rays"] = rays;
  j["wall_s_median"] = wall;
  j["cpu_s_median"] = cpu;
  j["wall_s"] = t.wall_s;
  j["cpu_s"] = t.cpu_s;
  j["rays_per_s"] = rays_per_s;
  j["rays_per_cpu_s"] = rays / cpu;
  j["achieved_flop_per_s"] = flops_per_ray * rays_per_s;
  j["fraction_of_matmul_peak"] = flops_per_ray * rays_per_s / peak_flops;
  return j;
}

}  // namespace

namespace {

// Names with their summed microseconds, largest first (ties by name).
std::vector<std::pair<std::string, double>> largest_first(const std::map<std::string, double>& us) {
  std::vector<std::pair<std::string, double>> v(us.begin(), us.end());
  std::sort(v.begin(), v.end(), [](const auto& a, const auto& b) {
    return a.second != b.second ? a.second > b.second : a.first < b.first;
  });
  return v;
}

}  // namespace

nlohmann::json trace_summary(const std::string& trace_json, int64_t steps, size_t top) {
  if (steps < 1) throw std::invalid_argument("trace_summary: steps must be >= 1");
  const auto parsed = nlohmann::json::parse(trace_json, nullptr, /*allow_exceptions=*/false);
  const auto& events = parsed.is_object() && parsed.contains("traceEvents") ? parsed["traceEvents"] : parsed;
  if (!events.is_array()) throw std::invalid_argument("trace_summary: not a Chrome trace (no array of events)");
  struct Event {
    double start, end;
    std::string name;
  };
  std::map<std::string, std::vector<Event>> by_thread;
  // Kineto's device-side events (a CUDA trace): kernels, copies and fills, each timed on the GPU.
  std::map<std::string, double> device_us;
  std::map<std::string, int64_t> device_calls;
  double device_total_us = 0;
  int64_t device_events = 0;
  for (const auto& e : events) {
    if (!e.is_object() || e.value("ph", "") != "X") continue;
    if (!e.contains("ts") || !e.contains("dur") || !e["ts"].is_number() || !e["dur"].is_number())
      throw std::invalid_argument("trace_summary: an \"X\" event without numeric ts and dur");
    const std::string cat = e.contains("cat") && e["cat"].is_string() ? e["cat"].get<std::string>() : "";
    if (cat == "gpu_user_annotation") continue;  // a span over kernels listed on their own
    const double ts = e["ts"].get<double>(), dur = e["dur"].get<double>();
    if (cat == "kernel" || cat == "gpu_memcpy" || cat == "gpu_memset") {
      const std::string name = e.value("name", "?").substr(0, kMaxOpName);
      device_us[name] += dur;
      device_calls[name] += 1;
      device_total_us += dur;
      ++device_events;
      continue;
    }
    by_thread[e.contains("tid") ? e["tid"].dump() : ""].push_back({ts, ts + dur, e.value("name", "?")});
  }
  std::map<std::string, double> self_us;
  std::map<std::string, int64_t> calls;
  int64_t ops = 0;
  double total_us = 0;
  for (auto& [tid, list] : by_thread) {
    // Parents first: earlier start, and the longer of two that start together.
    std::sort(list.begin(), list.end(),
              [](const Event& a, const Event& b) { return a.start != b.start ? a.start < b.start : a.end > b.end; });
    std::vector<double> child_us(list.size(), 0.0);
    std::vector<size_t> open;  // indices of the enclosing events
    for (size_t i = 0; i < list.size(); ++i) {
      while (!open.empty() && list[open.back()].end <= list[i].start) open.pop_back();
      if (!open.empty()) child_us[open.back()] += list[i].end - list[i].start;
      open.push_back(i);
    }
    for (size_t i = 0; i < list.size(); ++i) {
      const double self = std::max(0.0, list[i].end - list[i].start - child_us[i]);
      self_us[list[i].name] += self;
      calls[list[i].name] += 1;
      total_us += self;
      ++ops;
    }
  }
  const auto ranked = largest_first(self_us);
  const double per_step = static_cast<double>(steps);
  nlohmann::json out{{"steps", steps},
                     {"ops_per_step", static_cast<double>(ops) / per_step},
                     {"self_ms_per_step", total_us / 1000.0 / per_step},
                     {"top", nlohmann::json::array()}};
  for (size_t i = 0; i < std::min(top, ranked.size()); ++i)
    out["top"].push_back({{"op", ranked[i].first},
                          {"self_ms_per_step", ranked[i].second / 1000.0 / per_step},
                          {"calls_per_step", static_cast<double>(calls[ranked[i].first]) / per_step}});
  if (device_events > 0) {
    const auto by_time = largest_first(device_us);
    nlohmann::json gpu{{"events_per_step", static_cast<double>(device_events) / per_step},
                       {"busy_ms_per_step", device_total_us / 1000.0 / per_step},
                       {"top", nlohmann::json::array()}};
    for (size_t i = 0; i < std::min(top, by_time.size()); ++i)
      gpu["top"].push_back({{"kernel", by_time[i].first},
                            {"ms_per_step", by_time[i].second / 1000.0 / per_step},
                            {"share", by_time[i].second / device_total_us},
                            {"calls_per_step", static_cast<double>(device_calls[by_time[i].first]) / per_step}});
    out["gpu"] = gpu;
  }
  return out;
}

nlohmann::json bench_report(const Config& cfg, const BenchOptions& o, const BenchMeasurements& m) {
  const FlopCount f = model_flops_per_ray(cfg.model);
  const double n = static_cast<double>(o.matmul_size);
  const double matmul_flops = kFlopPerMac * n * n * n;
  const double peak = matmul_flops / m.matmul.wall_median();
  const double render_rays = static_cast<double>(o.render_rays > 0 ? o.render_rays : o.train_rays);
  const double pixels = static_cast<double>(o.image_side) * static_cast<double>(o.image_side);

  nlohmann::json j;
  j["config"] = cfg.source;
  j["device"] = o.device.str();
  j["threads"] = m.threads;
  const char* coretype = std::getenv("OPENBLAS_CORETYPE");
  j["openblas_coretype"] = coretype ? nlohmann::json(coretype) : nlohmann::json(nullptr);
  j["parameters"] = m.parameters;
  j["repetitions"] = {{"warmup", o.warmup}, {"timed", o.steps}, {"statistic", "median"}};
  j["flops_per_ray"] = {{"forward", f.forward},
                        {"train", f.train()},
                        {"counted", "matrix products only (GEMMs + attention); element-wise ops excluded"}};
  j["precision"] = name_of(cfg.compute.precision);
  j["attention"] = name_of(cfg.compute.attention);
  j["cpu_split"] = name_of(cfg.compute.cpu_split);
  j["device_step"] = m.device_step;
  j["cuda_graph"] = m.graph;
  j["matmul_peak"] = {{"n", o.matmul_size},
                      {"dtype", m.matmul_dtype},
                      {"flop_per_s", peak},
                      {"wall_s_median", m.matmul.wall_median()},
                      {"cpu_s_median", m.matmul.cpu_median()},
                      {"wall_s", m.matmul.wall_s}};
  j["train"] = timing_json(m.train, static_cast<double>(o.train_rays), f.train(), peak);
  j["train"]["includes"] = "Trainer::step: ray draw + forward + backward + Adam step";
  j["train"]["micro_batch"] = o.micro_batch > 0 ? std::min(o.micro_batch, o.train_rays) : o.train_rays;
  auto render = timing_json(m.render, render_rays, f.forward, peak);
  render["includes"] = "inference forward (InferenceMode), one chunk per repetition";
  render["image_side"] = o.image_side;
  render["seconds_per_image"] = pixels / render["rays_per_s"].get<double>();
  render["seconds_per_image_note"] = "extrapolated: pixels / measured render rays/s";
  j["render"] = render;
  j["peak_memory_bytes"] = m.peak_memory_bytes;
  j["peak_memory_source"] = m.peak_memory_source;
  return j;
}

}  // namespace ablenerf
