#include "train/bench.h"

#include <sys/resource.h>
#include <torch/cuda.h>
#include <torch/csrc/autograd/profiler_legacy.h>
#include <torch/version.h>

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <memory>
#include <set>
#include <functional>
#include <sstream>
#include <string>
#include <stdexcept>

#include "eval/camera_path.h"
#include "kernels/cpu_features.h"
#include "kernels/cpu_parallel.h"
#include "kernels/bf16_gemm.h"
#include "kernels/block_tail.h"
#include "kernels/packed_attention.h"
#include "kernels/small_gemm.h"
#include "model/ab_transformer.h"
#include "model/able_nerf.h"
#include "model/attention.h"
#include "model/compute.h"
#include "train/trainer.h"
#include "util/fs.h"
#include "train/train_config.h"
#include "model/compute_config.h"
#include "model/model_config.h"

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

constexpr double kCameraDistance = 4.0;
constexpr double kDirectionJitter = 0.1;
// The in-memory training split of the benchmark: a few Blender-like views (800x800, focal of
// lego's 0.6911 rad field of view), random colours.
constexpr int64_t kBenchViews = 4;
constexpr double kBlenderFocal = 1111.111;
constexpr int64_t kBytesPerKiB = 1024;

}  // namespace

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
  s.images = torch::rand({kBenchViews, side, side, kRgbChannels}, gen);
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

// What `run` does under LibTorch's legacy profiler (the calling thread's ops), as Chrome trace JSON.
std::string legacy_trace(const std::function<void()>& run) {
  std::ostringstream trace;
  {
    torch::autograd::profiler::RecordProfile record(trace);
    run();
  }
  return trace.str();
}

// `steps` more training steps under LibTorch's profiler, as Chrome trace JSON. On CUDA with
// LibTorch >= 2: Kineto, the host's ops and the GPU's kernels, memcpys and memsets (CUPTI); so the
// trace says where GPU time goes inside a CUDA graph's replay as well. Otherwise the legacy
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
  return legacy_trace([&] {
    for (int64_t i = 0; i < steps; ++i) trainer.step();
    trainer.flush();
  });
}

// A quiet trainer of `cfg` set up on the in-memory split of `image_side` pixels (bench_split).
std::unique_ptr<Trainer> bench_trainer(const Config& cfg, const torch::Device& device, int64_t image_side,
                                       uint64_t seed) {
  TrainOptions to;
  to.device = device;
  to.quiet = true;
  auto trainer = std::make_unique<Trainer>(cfg, to);
  trainer->setup(bench_split(image_side, seed), bench_intrinsics(image_side));
  return trainer;
}

// Untimed steps first; with a CUDA graph, until it is captured (the capture itself is not timed).
// `cfg`: the trainer's config.
void warm_up(Trainer& trainer, const Config& cfg, int64_t steps) {
  const bool graph = trainer.device_form() && cfg.get<TrainConfig>().graph;
  for (int64_t i = 0; i < steps || (graph && !trainer.graph_captured()); ++i) trainer.step();
}

}  // namespace

std::vector<ProductTiming> time_token_products(int64_t width, int64_t ff_ratio, int64_t tokens) {
  // Enough calls per timing to read the clock well (~2 ms), the median of seven timings.
  constexpr double kFlopPerTiming = 2e8;
  constexpr int kTimings = 7;
  const int64_t e = width, f = width * ff_ratio, m = tokens;
  std::vector<ProductTiming> list = {{"qkv projection", m, 3 * e, e, false},
                                     {"output projection", m, e, e, false},
                                     {"feed-forward in", m, f, e, false},
                                     {"feed-forward out", m, e, f, false},
                                     {"qkv input gradient", m, e, 3 * e, false},
                                     {"qkv weight gradient", 3 * e, e, m, true},
                                     {"feed-forward in weight gradient", f, e, m, true}};
  for (auto& p : list) {
    const int64_t a_size = p.m * p.k, b_size = p.k * p.n;
    const auto a = torch::rand({a_size}), b = torch::rand({b_size});
    auto c = torch::empty({p.m * p.n});
    const int64_t lda = p.trans_a ? p.m : p.k;
    const double flop = kFlopPerMac * static_cast<double>(p.m * p.n * p.k);
    const int64_t calls = std::max<int64_t>(1, static_cast<int64_t>(kFlopPerTiming / flop));
    const auto run = [&] {
      for (int64_t i = 0; i < calls; ++i)
        small_gemm(p.trans_a, p.m, p.n, p.k, 1.0f, a.data_ptr<float>(), lda, b.data_ptr<float>(), p.n,
                   c.data_ptr<float>(), p.n);
    };
    p.seconds = time_it(torch::kCPU, /*warmup=*/1, kTimings, run).wall_median() / static_cast<double>(calls);
    if (!cpu_has_bf16_products()) continue;
    Bf16Operand packed;
    const auto run_bf16 = [&] {
      for (int64_t i = 0; i < calls; ++i) {
        packed.pack(b.data_ptr<float>(), p.k, p.n, p.n, 1);
        if (p.trans_a)
          bf16_gemm_at(p.m, a.data_ptr<float>(), lda, packed, c.data_ptr<float>(), p.n);
        else
          bf16_gemm(p.m, a.data_ptr<float>(), lda, packed, c.data_ptr<float>(), p.n);
      }
    };
    p.bf16_seconds = time_it(torch::kCPU, /*warmup=*/1, kTimings, run_bf16).wall_median() / static_cast<double>(calls);
  }
  return list;
}

std::vector<KernelTiming> time_token_kernels(int64_t width, int64_t heads, int64_t ff_ratio, int64_t samples,
                                             int64_t rays) {
  constexpr int kTimings = 15;
  const SerialIntraOp one_thread;
  const int64_t e = width, f = width * ff_ratio, l = samples + 1;
  auto gen = at::detail::createCPUGenerator(7);
  const auto leaf = [&](std::vector<int64_t> sizes) { return (torch::randn(sizes, gen) * 0.5).requires_grad_(true); };
  const auto mask = ray_attention_mask(samples);
  const double scale = 1.0 / std::sqrt(static_cast<double>(e / heads));
  const auto qkv = leaf({rays, l, 3 * e}), x = leaf({rays, l, e}), attended = leaf({rays, l, e});
  const BlockTailWeights w{leaf({e, e}), leaf({e}),    leaf({e}), leaf({e}), leaf({f, e}),
                           leaf({f}),    leaf({e, f}), leaf({e}), leaf({e}), leaf({e})};
  const auto upstream = torch::randn({rays, l, e}, gen);
  const auto time = [&](const std::function<torch::Tensor()>& forward) {
    const auto inference = [&] {
      const torch::NoGradGuard no_grad;
      forward();
    };
    const auto train = [&] { forward().backward(upstream); };
    return std::make_pair(time_it(torch::kCPU, 2, kTimings, inference).wall_median(),
                          time_it(torch::kCPU, 2, kTimings, train).wall_median());
  };
  std::vector<KernelTiming> list;
  const auto attention = time([&] { return packed_self_attention(qkv, heads, mask, scale); });
  list.push_back({"attention core (ray mask)", rays, l, attention.first, attention.second});
  const auto tail = time([&] { return block_tail(x, attended, w, kLayerNormEps); });
  list.push_back({"block tail", rays, l, tail.first, tail.second});
  return list;
}

double training_rays_per_s(const Config& cfg, const torch::Device& device) {
  constexpr int64_t kWarmup = 3, kTimed = 5, kImageSide = 32;
  Config c = cfg;
  TrainConfig& tc = c.get<TrainConfig>();
  tc.time_budget_s = 0;
  tc.micro_batch = std::min(tc.micro_batch, tc.rays_per_step);
  const auto trainer = bench_trainer(c, device, kImageSide, static_cast<uint64_t>(tc.seed));
  warm_up(*trainer, c, kWarmup);
  const Timing t = time_it(device, 0, kTimed, [&] { trainer->step(); });
  trainer->flush();
  return static_cast<double>(tc.rays_per_step) / t.wall_median();
}

BenchMeasurements measure(const Config& cfg, const BenchOptions& o) {
  BenchMeasurements m;
  m.threads = at::get_num_threads();
  const auto& d = o.device;
  const int64_t render_rays = o.render_rays > 0 ? o.render_rays : o.train_rays;
  const Precision precision = Compute::from_config(cfg.get<ComputeConfig>(), d, cfg.source).precision;
  m.precision = name_of(precision);
  // The trainer's own step (Trainer::step) on an in-memory split: the same rays, micro-batches,
  // loss, optimiser and (on CUDA) CUDA graph as `ablenerf train`.
  Config c = cfg;
  c.get<TrainConfig>().rays_per_step = o.train_rays;
  c.get<TrainConfig>().micro_batch = o.micro_batch > 0 ? std::min(o.micro_batch, o.train_rays) : o.train_rays;
  c.get<TrainConfig>().seed = static_cast<int64_t>(o.seed);
  c.get<TrainConfig>().time_budget_s = 0;
  const auto owned = bench_trainer(c, d, o.image_side, o.seed);
  Trainer& trainer = *owned;
  AbleNerf& model = trainer.model();
  m.parameters = model->parameter_count();
#ifdef ABLENERF_CUDA_MEMORY_STATS
  // After the first allocations: the caching allocator of a device exists only from then on.
  if (d.is_cuda()) c10::cuda::CUDACachingAllocator::resetPeakStats(d.index() < 0 ? 0 : d.index());
#endif
  m.device_step = trainer.device_form();
  warm_up(trainer, c, o.warmup);
  m.graph = trainer.graph_captured();
  m.train = time_it(d, 0, o.steps, [&] { trainer.step(); });
  trainer.flush();
  if (o.trace_steps > 0) m.trace_json = trace_steps(trainer, o.trace_steps, d);
  {
    const auto rays = bench_rays(render_rays, o.seed + 1, d);
    model->eval();
    const auto render = [&] {
      torch::InferenceMode guard;
      ForwardOptions fo;
      fo.coarse.colour = false;  // as the renderer: an image needs only the fine colour
      const auto out = model->forward(rays, o.near, o.far, fo);
      (void)out;
    };
    m.render = time_it(d, o.warmup, o.steps, render);
    if (o.trace_steps > 0 && !d.is_cuda())
      m.render_trace_json = legacy_trace([&] {
        for (int64_t i = 0; i < o.trace_steps; ++i) render();
      });
  }
  {
    // The peak in the precision the model's products run in on a GPU; on a CPU the float32 one
    // (sgemm), whatever the products' precision, so that the two precisions' shares compare.
    const bool bf16_peak = precision == Precision::Bf16 && d.is_cuda();
    const auto opts = torch::TensorOptions().device(d).dtype(bf16_peak ? torch::kBFloat16 : torch::kFloat);
    m.matmul_dtype = bf16_peak ? "bf16" : "fp32";
    const auto a = torch::randn({o.matmul_size, o.matmul_size}, opts);
    const auto b = torch::randn({o.matmul_size, o.matmul_size}, opts);
    auto c = torch::empty({o.matmul_size, o.matmul_size}, opts);
    m.matmul = time_it(d, 1, o.matmul_reps, [&] { torch::mm_out(c, a, b); });
  }

  if (d.is_cpu()) {
    const auto& mc = cfg.get<ModelConfig>();
    const int64_t workers = ray_workers(o.train_rays);
    const int64_t slice = (o.train_rays + workers - 1) / workers;
    m.products = time_token_products(mc.width, mc.ff_ratio, slice * (mc.samples + 1));
    m.kernels = time_token_kernels(mc.width, mc.heads, mc.ff_ratio, mc.samples, slice);
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

nlohmann::json bench_report(const Config& cfg, const BenchOptions& o, const BenchMeasurements& m) {
  // Each timing counts what its forward computes: training the coarse colour its config asks for,
  // rendering none (the renderer's forward).
  const TrainConfig& tc = cfg.get<TrainConfig>();
  const FlopCount f = model_flops_per_ray(cfg.get<ModelConfig>(), tc.coarse_work());
  const FlopCount f_render = model_flops_per_ray(cfg.get<ModelConfig>(), {/*colour=*/false});
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
  j["openblas_core"] = blas_core_name();  // the kernels OpenBLAS runs (kernels/cpu_parallel.h)
  // The project's CPU kernels' widest form here (kernels/cpu_features.h: the CPU, capped by ABLENERF_CPU_ISA).
  j["cpu_kernels"] = cpu_has_avx512() ? "avx512" : cpu_has_avx2_fma() ? "avx2" : "baseline";
  j["cpu_bf16_products"] = cpu_has_bf16_products();
  j["parameters"] = m.parameters;
  j["repetitions"] = {{"warmup", o.warmup}, {"timed", o.steps}, {"statistic", "median"}};
  j["flops_per_ray"] = {{"forward", f_render.forward},
                        {"train", f.train()},
                        {"counted", "matrix products only (GEMMs + attention); element-wise ops excluded"}};
  j["precision"] = m.precision;
  j["attention"] = name_of(cfg.get<ComputeConfig>().attention);
  j["cpu_split"] = name_of(cfg.get<ComputeConfig>().cpu_split);
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
  auto render = timing_json(m.render, render_rays, f_render.forward, peak);
  render["includes"] = "inference forward (InferenceMode), one chunk per repetition";
  render["image_side"] = o.image_side;
  render["seconds_per_image"] = pixels / render["rays_per_s"].get<double>();
  render["seconds_per_image_note"] = "extrapolated: pixels / measured render rays/s";
  j["render"] = render;
  if (!m.products.empty()) {
    // Against one thread's share of the measured peak (the products run one per thread): the peak
    // over the threads the sgemm kept busy (its CPU time over its wall time), which are BLAS's
    // own and need not be the intra-op count.
    const double busy = m.matmul.wall_median() > 0 ? m.matmul.cpu_median() / m.matmul.wall_median() : 1.0;
    const double share = peak / std::max(1.0, std::round(busy));
    nlohmann::json list = nlohmann::json::array();
    for (const auto& p : m.products) {
      const double rate = kFlopPerMac * static_cast<double>(p.m * p.n * p.k) / p.seconds;
      list.push_back({{"name", p.name},
                      {"m", p.m},
                      {"n", p.n},
                      {"k", p.k},
                      {"trans_a", p.trans_a},
                      {"seconds_median", p.seconds},
                      {"flop_per_s", rate},
                      {"fraction_of_thread_peak", rate / share}});
      if (p.bf16_seconds > 0) {
        list.back()["bf16_seconds_median"] = p.bf16_seconds;
        list.back()["bf16_speedup"] = p.seconds / p.bf16_seconds;
      }
    }
    j["token_products"] = {
        {"kernel", "small_gemm, one thread"},
        {"bf16_kernel", std::string("bf16_gemm, form ") + bf16_gemm_form_name(bf16_gemm_best_form())},
        {"thread_peak_flop_per_s", share},
        {"note", "the transformer's products at one training slice's shapes, each timed alone"},
        {"products", list}};
    auto kernels = nlohmann::json::array();
    for (const auto& k : m.kernels)
      kernels.push_back({{"name", k.name},
                         {"rays", k.rays},
                         {"tokens", k.tokens},
                         {"forward_seconds_median", k.forward_seconds},
                         {"forward_backward_seconds_median", k.train_seconds}});
    j["token_kernels"] = {
        {"note",
         "the AB transformer layer's fused CPU kernels at one training slice's shapes, each alone on one thread"},
        {"kernels", kernels}};
  }
  j["peak_memory_bytes"] = m.peak_memory_bytes;
  j["peak_memory_source"] = m.peak_memory_source;
  return j;
}

}  // namespace ablenerf
