// The bench's arithmetic: the FLOP count against a hand count and the published estimate
// (docs/MODEL.md, section 11), the report's derived numbers from given measurements, and a tiny
// end-to-end run that must produce every field (no timing assertions).
#include <gtest/gtest.h>

#include "train/bench.h"
#include "test_util.h"
#include "model/model_config.h"
#include "train/train_config.h"

#include <cmath>

namespace ablenerf {
namespace {

ModelConfig hand_config() {
  ModelConfig m;
  m.width = 4;  // E
  m.heads = 2;
  m.ff_ratio = 2;  // F = 8
  m.coarse_layers = 1;
  m.fine_layers = 1;
  m.samples = 2;      // S = 2, L = 3 tokens
  m.ipe_degrees = 1;  // P = 6 IPE features
  m.le_count = 1;     // N = 1
  m.le_layers = 1;
  m.view_encoding = ViewEncoding::Release;  // V = 27
  return m;
}

TEST(BenchFlops, TinyConfigMatchesHandCount) {
  // Forward, 2 FLOP per multiply-add, per ray:
  //  view token 27->4: 2*27*4 = 216
  //  per pass: volume MLP 2*2*6*4 + 3*(2*2*4*4) = 96 + 192 = 288
  //            AB block (L=3): QKV 2*3*4*12=288, scores 2*3*4*3=72, values 72, out 2*3*4*4=96,
  //                            FF 2*3*4*8 + 2*3*8*4 = 384  -> 912
  //            probe 2*1*4*3 = 24; ray head 2*4*3 = 24
  //            LE cross (N=1 over S=2): KV 2*2*4*8=128, 16, 16, out 32, FF 128 -> 320
  //            LE self (N=1): QKV 96, 8, 8, out 32, FF 128 -> 272
  //            decode (1 query over N=1): Q 32, KV 64, 8, 8, out 32, FF 128 -> 272
  //            LE head: 2*(4+27)*4 + 2*4*3 = 248 + 24 = 272
  //            pass = 288 + 912 + 24 + 24 + 320 + 272 + 272 + 272 = 2384
  //  forward = 216 + 2*2384 = 4984
  const double forward = 216 + 2 * 2384;
  // Backward = 2 x forward, less the products whose constant operand gets no gradient:
  //  view token (-216), first volume layer in each pass (-96 each), probe in each pass (-48 each).
  const double backward = 2 * forward - 216 - 2 * 96 - 2 * 48;
  const FlopCount f = model_flops_per_ray(hand_config());
  EXPECT_DOUBLE_EQ(f.forward, forward);
  EXPECT_DOUBLE_EQ(f.backward, backward);
  EXPECT_DOUBLE_EQ(f.train(), 14448.0);
}

// The last AB layer of a pass that feeds no LE transformer computes the ray token's row alone: one
// query against the L = 3 keys: Q 2*1*4*4 = 32, K/V 2*3*4*8 = 192, scores 2*1*4*3 = 24, values 24,
// out 32, FF 2*1*4*8 + 2*1*8*4 = 128 -> 432 (the full block: 912).
constexpr double kRayRowBlock = 432;

TEST(BenchFlops, NoLeDropsTheLeBranch) {
  ModelConfig m = hand_config();
  m.le_count = 0;
  // Per pass without LE: 288 + 432 + 24 + 24 = 768; no view token.
  EXPECT_DOUBLE_EQ(model_flops_per_ray(m).forward, 2 * (288 + kRayRowBlock + 24 + 24));
}

// What the coarse pass skips (CoarseWork): rendering computes no coarse colour (its last layer the
// ray token's row, no colour heads, no LE branch); training without the coarse LE transformer keeps
// the ray colour head, and with the view head the LE colour head on the ray token (272).
TEST(BenchFlops, CoarseWorkCountsWhatTheCoarsePassComputes) {
  const ModelConfig m = hand_config();
  const double full_pass = 2384, view_token = 216;
  const double row_pass = 288 + kRayRowBlock + 24;  // volume MLP, the last layer's row, the probe
  EXPECT_DOUBLE_EQ(model_flops_per_ray(m, {/*colour=*/false}).forward, view_token + row_pass + full_pass);
  EXPECT_DOUBLE_EQ(model_flops_per_ray(m, {true, /*le=*/false, /*view_head=*/false}).forward,
                   view_token + row_pass + 24 + full_pass);
  EXPECT_DOUBLE_EQ(model_flops_per_ray(m, {true, false, /*view_head=*/true}).forward,
                   view_token + row_pass + 24 + 272 + full_pass);
  // Backward of the rendering count: 2 x forward less the constant-input products (view token 216,
  // first volume layer 96 per pass) and the probes (48 per pass).
  const FlopCount r = model_flops_per_ray(m, {false});
  EXPECT_DOUBLE_EQ(r.backward, 2 * r.forward - 216 - 2 * 96 - 2 * 48);
}

// The grid front end: the volume MLP's input is the grid's L x F features beside the IPE bands, and
// the grid's features take a gradient (one more product of their width); the proposal field adds
// its two products per proposal interval, both with gradients.
TEST(BenchFlops, GridAndProposalAddTheirProducts) {
  ModelConfig m = hand_config();
  m.le_count = 0;
  m.embedding = Embedding::Grid;
  m.grid_levels = 3;
  m.grid_features = 2;     // G = 6 grid features
  m.grid_ipe_degrees = 1;  // beside P = 6 IPE features: 12 inputs
  // Per pass: volume MLP 2*2*12*4 + 192 = 384 (forward), the rest as without LE (480).
  const FlopCount g = model_flops_per_ray(m);
  EXPECT_DOUBLE_EQ(g.forward, 2 * (384 + kRayRowBlock + 24 + 24));
  // Backward: 2 x forward less the constant-input products (2*2*12*4 = 192 per pass) and the probes
  // (2 x 24 per pass: no backward), plus the grid features' gradient 2*2*4*6 = 96 per pass.
  EXPECT_DOUBLE_EQ(g.backward, 2 * g.forward - 2 * 192 - 2 * 48 + 2 * 96);
  m.proposal_samples = 5;
  m.proposal_levels = 2;  // 4 features per proposal read
  const FlopCount p = model_flops_per_ray(m);
  const double proposal = 2 * 5 * 4 * 16 + 2 * 5 * 16 * 1;  // 640 + 160
  EXPECT_DOUBLE_EQ(p.forward, g.forward + proposal);
  EXPECT_DOUBLE_EQ(p.backward, g.backward + 2 * proposal);
}

TEST(BenchFlops, BlenderPresetMatchesSpecEstimate) {
  // docs/MODEL.md, section 11: ~0.43 G multiply-adds (~0.86 GFLOP) forward, ~2.6 GFLOP forward+backward per ray.
  const FlopCount f =
      model_flops_per_ray(Config::load(test::source_dir() + "/configs/blender.toml").get<ModelConfig>());
  EXPECT_NEAR(f.forward, 0.86e9, 0.03 * 0.86e9);
  EXPECT_NEAR(f.train(), 2.6e9, 0.03 * 2.6e9);
}

TEST(BenchMedian, OddEvenAndUnsorted) {
  EXPECT_DOUBLE_EQ(median({3.0, 1.0, 2.0}), 2.0);
  EXPECT_DOUBLE_EQ(median({4.0, 1.0, 3.0, 2.0}), 2.5);
  EXPECT_THROW(median({}), std::invalid_argument);
}

TEST(BenchReport, DerivedNumbersFollowFromMeasurements) {
  Config cfg;
  cfg.get<ModelConfig>() = hand_config();
  BenchOptions o;
  o.train_rays = 10;
  o.render_rays = 40;
  o.matmul_size = 100;  // 2e6 FLOP per sgemm
  o.image_side = 20;    // 400 pixels
  BenchMeasurements m;
  m.train.wall_s = {0.5, 0.2, 0.3};  // median 0.3 s -> 33.3 rays/s
  m.train.cpu_s = {0.6, 0.4, 0.5};   // median 0.5
  m.render.wall_s = {0.1, 0.1};      // 400 rays/s -> 1 s per 400-pixel image
  m.render.cpu_s = {0.2, 0.2};
  m.matmul.wall_s = {0.001, 0.002, 0.004};  // median 0.002 s -> 1e9 FLOP/s
  m.matmul.cpu_s = {0.001, 0.002, 0.004};
  m.peak_memory_bytes = 123;
  m.peak_memory_source = "test";
  const auto j = bench_report(cfg, o, m);
  EXPECT_DOUBLE_EQ(j["matmul_peak"]["flop_per_s"].get<double>(), 1e9);
  EXPECT_DOUBLE_EQ(j["train"]["rays_per_s"].get<double>(), 10 / 0.3);
  EXPECT_DOUBLE_EQ(j["train"]["rays_per_cpu_s"].get<double>(), 20.0);
  EXPECT_DOUBLE_EQ(j["train"]["achieved_flop_per_s"].get<double>(), 14448.0 * 10 / 0.3);
  EXPECT_DOUBLE_EQ(j["train"]["fraction_of_matmul_peak"].get<double>(), 14448.0 * 10 / 0.3 / 1e9);
  EXPECT_DOUBLE_EQ(j["render"]["rays_per_s"].get<double>(), 400.0);
  // Rendering computes no coarse colour: 216 + 744 + 2384 = 3344 per ray (BenchFlops above).
  EXPECT_DOUBLE_EQ(j["render"]["achieved_flop_per_s"].get<double>(), 3344.0 * 400);
  EXPECT_DOUBLE_EQ(j["render"]["seconds_per_image"].get<double>(), 1.0);
  EXPECT_EQ(j["peak_memory_bytes"].get<int64_t>(), 123);
  EXPECT_DOUBLE_EQ(j["flops_per_ray"]["forward"].get<double>(), 3344.0);
  EXPECT_FALSE(j.contains("token_products"));  // none measured

  // A token product of 10 x 20 x 30 (12,000 FLOP) in 1e-5 s: 1.2e9 FLOP/s, against one thread's
  // share of the 1e9 FLOP/s peak that kept 2 threads busy (CPU time twice the wall time, whatever
  // the intra-op count): 2.4 of it.
  m.threads = 1;
  m.matmul.cpu_s = {0.002, 0.004, 0.008};
  m.products = {{"qkv projection", 10, 20, 30, false, 1e-5}};
  m.kernels = {{"block tail", 8, 17, 2e-5, 6e-5}};
  const auto with = bench_report(cfg, o, m);
  const auto& k = with["token_kernels"]["kernels"].at(0);
  EXPECT_EQ(k["name"], "block tail");
  EXPECT_EQ(k["rays"].get<int64_t>(), 8);
  EXPECT_DOUBLE_EQ(k["forward_backward_seconds_median"].get<double>(), 6e-5);
  EXPECT_DOUBLE_EQ(with["token_products"]["thread_peak_flop_per_s"].get<double>(), 5e8);
  const auto& p = with["token_products"]["products"].at(0);
  EXPECT_EQ(p["name"], "qkv projection");
  EXPECT_DOUBLE_EQ(p["flop_per_s"].get<double>(), 1.2e9);
  EXPECT_DOUBLE_EQ(p["fraction_of_thread_peak"].get<double>(), 2.4);
}

// The fused kernels run at the AB layer's shapes: rays of samples + 1 tokens, both timings positive.
TEST(BenchRun, TokenKernelsHaveTheLayersShapes) {
  const auto list = time_token_kernels(/*width=*/32, /*heads=*/2, /*ff_ratio=*/2, /*samples=*/16, /*rays=*/20);
  ASSERT_EQ(list.size(), 2u);
  EXPECT_EQ(list[0].name, "attention core (ray mask)");
  EXPECT_EQ(list[1].name, "block tail");
  for (const auto& k : list) {
    EXPECT_EQ(k.rays, 20) << k.name;
    EXPECT_EQ(k.tokens, 17) << k.name;
    EXPECT_GT(k.forward_seconds, 0) << k.name;
    EXPECT_GT(k.train_seconds, 0) << k.name;
  }
}

// The products are the transformer's at the given width, feed-forward ratio and tokens, and
// time_token_products computes what it times (no assertion on the time beyond being positive).
TEST(BenchRun, TokenProductsHaveTheModelsShapes) {
  const auto list = time_token_products(/*width=*/4, /*ff_ratio=*/2, /*tokens=*/30);
  ASSERT_EQ(list.size(), 7u);
  EXPECT_EQ(list[0].name, "qkv projection");
  EXPECT_EQ(std::vector<int64_t>({list[0].m, list[0].n, list[0].k}), std::vector<int64_t>({30, 12, 4}));
  EXPECT_EQ(std::vector<int64_t>({list[3].m, list[3].n, list[3].k}), std::vector<int64_t>({30, 4, 8}));
  EXPECT_TRUE(list[5].trans_a);  // the qkv weight's gradient: 12 x 4, reduced over the 30 tokens
  EXPECT_EQ(std::vector<int64_t>({list[5].m, list[5].n, list[5].k}), std::vector<int64_t>({12, 4, 30}));
  for (const auto& p : list) EXPECT_GT(p.seconds, 0) << p.name;
}

// A run of the hand-counted model small enough for a test: 4 rays, 2 timed steps.
Config tiny_bench_config() {
  Config cfg;
  cfg.get<ModelConfig>() = hand_config();
  return cfg;
}
BenchOptions tiny_bench_options() {
  BenchOptions o;
  o.train_rays = 4;
  o.steps = 2;
  o.warmup = 1;
  o.matmul_size = 32;
  o.matmul_reps = 2;
  return o;
}

TEST(BenchRun, TinyRunReportsEveryField) {
  const Config cfg = tiny_bench_config();
  const BenchOptions o = tiny_bench_options();
  const auto m = measure(cfg, o);
  ASSERT_EQ(m.train.wall_s.size(), 2u);
  ASSERT_EQ(m.render.cpu_s.size(), 2u);
  EXPECT_GT(m.peak_memory_bytes, 0);
  EXPECT_GT(m.parameters, 0);
  const auto j = bench_report(cfg, o, m);
  for (const char* key : {"config", "device", "threads", "parameters", "flops_per_ray", "matmul_peak", "train",
                          "render", "peak_memory_bytes", "peak_memory_source"})
    EXPECT_TRUE(j.contains(key)) << key;
  for (const char* part : {"train", "render"})
    for (const char* key : {"rays", "rays_per_s", "rays_per_cpu_s", "wall_s_median", "cpu_s_median",
                            "achieved_flop_per_s", "fraction_of_matmul_peak"})
      EXPECT_TRUE(j[part].contains(key)) << part << "." << key;
  EXPECT_TRUE(j["render"].contains("seconds_per_image"));
  EXPECT_EQ(j["render"]["rays"].get<double>(), 4.0);  // render chunk defaults to the train batch
  // On the CPU the token products at one slice's shapes: 4 rays on one or two threads, 3 tokens a ray.
  ASSERT_EQ(m.products.size(), 7u);
  EXPECT_TRUE(m.products[0].m == 12 || m.products[0].m == 6) << m.products[0].m;
  EXPECT_EQ(j["token_products"]["products"].size(), 7u);
}

TEST(BenchTrace, SelfTimesFromNestedEvents) {
  // Two steps on two threads. Thread 1: "step" 0-100 holding "mm" 10-40 (holding "copy" 20-25)
  // and "add" 50-60, then "mm" 200-230 on its own; thread 2: "add" 0-7. Self times, us:
  // step 100 - 30 - 10 = 60; mm (30 - 5) + 30 = 55; copy 5; add 10 + 7 = 17. Total 137.
  const std::string trace = R"([
    {"name": "mm", "ph": "X", "ts": 10, "dur": 30, "tid": 1},
    {"name": "step", "ph": "X", "ts": 0, "dur": 100, "tid": 1},
    {"name": "copy", "ph": "X", "ts": 20, "dur": 5, "tid": 1},
    {"name": "add", "ph": "X", "ts": 50, "dur": 10, "tid": 1},
    {"name": "mm", "ph": "X", "ts": 200, "dur": 30, "tid": 1},
    {"name": "add", "ph": "X", "ts": 0, "dur": 7, "tid": 2},
    {"name": "marker", "ph": "i", "ts": 5, "tid": 1}
  ])";
  const auto j = trace_summary(trace, 2, 3);
  EXPECT_EQ(j["steps"].get<int64_t>(), 2);
  EXPECT_DOUBLE_EQ(j["ops_per_step"].get<double>(), 3.0);
  EXPECT_NEAR(j["self_ms_per_step"].get<double>(), 0.137 / 2, 1e-12);
  ASSERT_EQ(j["top"].size(), 3u);
  EXPECT_EQ(j["top"][0]["op"], "step");
  EXPECT_NEAR(j["top"][0]["self_ms_per_step"].get<double>(), 0.030, 1e-12);
  EXPECT_EQ(j["top"][1]["op"], "mm");
  EXPECT_NEAR(j["top"][1]["self_ms_per_step"].get<double>(), 0.0275, 1e-12);
  EXPECT_DOUBLE_EQ(j["top"][1]["calls_per_step"].get<double>(), 1.0);
  EXPECT_EQ(j["top"][2]["op"], "add");
  EXPECT_NEAR(j["top"][2]["self_ms_per_step"].get<double>(), 0.0085, 1e-12);
  // The {"traceEvents": [...]} form reads alike; anything else is refused.
  EXPECT_EQ(trace_summary(R"({"traceEvents": )" + trace + "}", 2, 3), j);
  EXPECT_THROW(trace_summary("{}", 1, 3), std::invalid_argument);
  EXPECT_THROW(trace_summary("not json", 1, 3), std::invalid_argument);
  EXPECT_THROW(trace_summary(R"([{"name": "x", "ph": "X", "ts": "a", "dur": 1}])", 1, 3), std::invalid_argument);
  EXPECT_FALSE(j.contains("stages"));  // no stage scopes in this trace
}

// The speed the image-size choice measures (train/image_size.h): positive and finite, from steps
// of the config's own batch. No assertion on its value: timing depends on the machine.
TEST(BenchRun, TrainingSpeedOfAConfig) {
  Config cfg = tiny_bench_config();
  cfg.get<TrainConfig>().rays_per_step = 8;
  cfg.get<TrainConfig>().micro_batch = 8;
  const double speed = training_rays_per_s(cfg, torch::kCPU);
  EXPECT_GT(speed, 0);
  EXPECT_TRUE(std::isfinite(speed));
}

TEST(BenchTrace, StagesTakeTheirWholeDurationAndCountTheOpsInside) {
  // One step: stage "ablenerf.a" 0-50 holding "mm" 5-20 (holding "copy" 6-8) and "add" 30-40;
  // "ablenerf.b" 60-70 holding "add" 61-62, then a second "ablenerf.b" 80-100 holding nothing;
  // "sum" 100-110 after them.
  const std::string trace = R"([
    {"name": "ablenerf.a", "ph": "X", "ts": 0, "dur": 50, "tid": 1},
    {"name": "mm", "ph": "X", "ts": 5, "dur": 15, "tid": 1},
    {"name": "copy", "ph": "X", "ts": 6, "dur": 2, "tid": 1},
    {"name": "add", "ph": "X", "ts": 30, "dur": 10, "tid": 1},
    {"name": "ablenerf.b", "ph": "X", "ts": 60, "dur": 10, "tid": 1},
    {"name": "add", "ph": "X", "ts": 61, "dur": 1, "tid": 1},
    {"name": "ablenerf.b", "ph": "X", "ts": 80, "dur": 20, "tid": 1},
    {"name": "sum", "ph": "X", "ts": 100, "dur": 10, "tid": 1}
  ])";
  const auto j = trace_summary(trace, 1, 10);
  ASSERT_TRUE(j.contains("stages"));
  ASSERT_EQ(j["stages"].size(), 2u);
  EXPECT_EQ(j["stages"][0]["stage"], "ablenerf.a");
  EXPECT_NEAR(j["stages"][0]["ms_per_step"].get<double>(), 0.050, 1e-12);
  EXPECT_DOUBLE_EQ(j["stages"][0]["ops_per_step"].get<double>(), 3.0);
  EXPECT_EQ(j["stages"][1]["stage"], "ablenerf.b");
  EXPECT_NEAR(j["stages"][1]["ms_per_step"].get<double>(), 0.030, 1e-12);
  EXPECT_DOUBLE_EQ(j["stages"][1]["calls_per_step"].get<double>(), 2.0);
  EXPECT_DOUBLE_EQ(j["stages"][1]["ops_per_step"].get<double>(), 1.0);
}

TEST(BenchTrace, DeviceEventsOfAKinetoTraceAreSummedApart) {
  // A CUDA trace: the host's "aten::mm" (0-50) launching "cudaLaunchKernel" (10-15), and on the
  // GPU's stream two "gemm" kernels (60 and 40 us), one "fill" memset (10 us) and an annotation
  // spanning them (left out). One step: gemm 100 us (2 calls, 100/110 of the busy time), fill 10.
  const std::string trace = R"json({"traceEvents": [
    {"name": "aten::mm", "cat": "cpu_op", "ph": "X", "ts": 0, "dur": 50, "tid": 1},
    {"name": "cudaLaunchKernel", "cat": "cuda_runtime", "ph": "X", "ts": 10, "dur": 5, "tid": 1},
    {"name": "gemm", "cat": "kernel", "ph": "X", "ts": 20, "dur": 60, "tid": 7},
    {"name": "gemm", "cat": "kernel", "ph": "X", "ts": 90, "dur": 40, "tid": 7},
    {"name": "Memset (Device)", "cat": "gpu_memset", "ph": "X", "ts": 130, "dur": 10, "tid": 7},
    {"name": "step", "cat": "gpu_user_annotation", "ph": "X", "ts": 20, "dur": 120, "tid": 7},
    {"ph": "f", "name": "flow", "ts": 20, "tid": 7}
  ]})json";
  const auto j = trace_summary(trace, 1, 5);
  EXPECT_DOUBLE_EQ(j["ops_per_step"].get<double>(), 2.0);  // the host's two events only
  EXPECT_NEAR(j["self_ms_per_step"].get<double>(), 0.050, 1e-12);
  ASSERT_TRUE(j.contains("gpu"));
  const auto& g = j["gpu"];
  EXPECT_DOUBLE_EQ(g["events_per_step"].get<double>(), 3.0);
  EXPECT_NEAR(g["busy_ms_per_step"].get<double>(), 0.110, 1e-12);
  ASSERT_EQ(g["top"].size(), 2u);
  EXPECT_EQ(g["top"][0]["kernel"], "gemm");
  EXPECT_NEAR(g["top"][0]["ms_per_step"].get<double>(), 0.100, 1e-12);
  EXPECT_NEAR(g["top"][0]["share"].get<double>(), 100.0 / 110.0, 1e-12);
  EXPECT_DOUBLE_EQ(g["top"][0]["calls_per_step"].get<double>(), 2.0);
  EXPECT_EQ(g["top"][1]["kernel"], "Memset (Device)");
  // A host-only trace has no "gpu" part.
  EXPECT_FALSE(trace_summary(R"([{"name": "mm", "ph": "X", "ts": 0, "dur": 3, "tid": 1}])", 1, 5).contains("gpu"));
}

TEST(BenchTrace, TinyRunRecordsTheStepsOps) {
  const Config cfg = tiny_bench_config();
  BenchOptions o = tiny_bench_options();
  o.trace_steps = 2;
  const auto m = measure(cfg, o);
  const auto j = trace_summary(m.trace_json, o.trace_steps, 5);
  // A training step runs products (the linear layers: ATen's or, in float32 on the CPU, the
  // project's node, kernels/linear_cpu.h) and their backward.
  EXPECT_GT(j["ops_per_step"].get<double>(), 20.0);
  bool has_product = false;
  for (const auto& e : nlohmann::json::parse(m.trace_json)) {
    const std::string name = e.value("name", "");
    has_product = has_product || name == "aten::addmm" || name == "aten::mm" || name == "ablenerf::linear_cpu";
  }
  EXPECT_TRUE(has_product);
  // The rendering forwards' trace beside it: products, and no backward node.
  const auto r = trace_summary(m.render_trace_json, o.trace_steps, 5);
  EXPECT_GT(r["ops_per_step"].get<double>(), 10.0);
  bool render_product = false, render_backward = false;
  for (const auto& e : nlohmann::json::parse(m.render_trace_json)) {
    const std::string name = e.value("name", "");
    render_product = render_product || name == "aten::addmm" || name == "aten::mm" || name == "ablenerf::linear_cpu";
    render_backward = render_backward || name.find("Backward") != std::string::npos;
  }
  EXPECT_TRUE(render_product);
  EXPECT_FALSE(render_backward);
  o.trace_steps = 0;
  const auto untraced = measure(cfg, o);
  EXPECT_TRUE(untraced.trace_json.empty());
  EXPECT_TRUE(untraced.render_trace_json.empty());
}

}  // namespace
}  // namespace ablenerf
