#!/usr/bin/env bash
# Build, test and measure ablenerf on a CUDA machine with PyTorch 2.x and no package registry
# (docs/GPU.md). Header-only and small dependencies travel in .carry/root (Debian packages
# unpacked here, see docs/GPU.md); LibTorch is the one inside the machine's PyTorch.
#   scripts/gpu.sh STAGE...    stages run in order; logs and results go to $OUT (default /tmp/gpu)
# Stages:
#   env        versions: GPU, driver, PyTorch, compiler, where nccl.h and gloo headers are
#   build      configure + build build-cuda (Release, every target)
#   test       ctest in build-cuda (the CPU test suites, built against the CUDA LibTorch)
#   gputest    the ctest label gpu (kernels against their references, graph vs eager steps)
#   bench      ablenerf bench on the GPU at the blender preset: 1024- and 8192-ray steps, bf16 + fused
#              + CUDA graph vs fp32 + plain + eager
#   peerbench  the authors' release on the same GPU (optional: ../shared/tools/peer when present, carried in .carry/peer)
#   peertrain  the release's own recipe on lego for $BUDGET seconds (default 300), PSNR on test views 0-5
#   lego5      ablenerf on lego for $BUDGET seconds with configs/budget.toml, PSNR on test views 0-5
#              (LEGO5_SET="k=v k=v": extra settings, e.g. LEGO5_SET=train.ray_sampling=error)
#   capture    real captures (CAPTURES, default .carry/fox4 .carry/fox4_sfm) for $CAPTURE_BUDGET s each + eval
#              (CAPTURE_CONFIG, default configs/budget.toml; CAPTURE_SET="k=v ..." for all of them,
#              CAPTURE_SET_<name>="k=v ..." for one, e.g. CAPTURE_SET_fox4_sfm=train.camera_refine=true;
#              CAPTURE_CONFIG_<name> its own preset; CAPTURE_EVAL_<name>="--align-cameras" its eval's options;
#              an entry DIR@NAME trains DIR under NAME, so one capture can run with several settings)
#   nccl       a one-process c10d/NCCL training run (WORLD_SIZE=1: the collective code path)
#   quality    the same short lego run in fp32 + plain and in bf16 + fused: PSNR side by side
#   lego8      lego at full resolution, blender preset, 8 minutes of training (steps from bench's rate)
#   lego8eval  evaluates that run on the first 20 test views (PSNR, SSIM, LPIPS)
#   versus     the fast settings' bench of $bin against $VERSUS_BIN (the previous binary), alternating,
#              ROUNDS rounds (default 3) at 1024- and 8192-ray steps: the medians side by side
#   profile    bench --trace at 1024-ray steps: the GPU's kernels by time per step (Kineto), trace in $OUT
#   attribute  the same step eagerly (train.graph=false) under the profiler: GPU time by the host op
#              that launched it (scripts/gpu_attribute.py; a graph's replay names no source)
#   view       the web viewer on the GPU: launch to first answer, render + PNG times at 32-800 pixels
set -uo pipefail
cd "$(dirname "$0")/.."
. scripts/lib.sh
OUT=${OUT:-/tmp/gpu}
mkdir -p "$OUT"
root=$PWD/.carry/root
export LD_LIBRARY_PATH=$root/usr/lib/x86_64-linux-gnu:$root/lib/x86_64-linux-gnu:${LD_LIBRARY_PATH:-}
bin=${ABLENERF_BIN:-build-cuda/ablenerf}  # another binary for a dry run of a stage on a CPU machine
lego=.carry/lego   # lego's train split + the first 20 test views (docs/GPU.md)
# LPIPS weights: the repository's assets/ copy, unless the fp32 original is carried.
[ -f .carry/weights/lpips_alex_v0.1.pt ] && export ABLENERF_LPIPS_WEIGHTS=$PWD/.carry/weights/lpips_alex_v0.1.pt

stamp() { echo "== $(date -u +%H:%M:%S) $*"; }

stage_env() {
  nvidia-smi --query-gpu=name,memory.total,driver_version,clocks.sm,clocks.max.sm --format=csv
  python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.version.cuda, 'cxx11abi', torch._C._GLIBCXX_USE_CXX11_ABI)"
  g++ --version | head -1; cmake --version | head -1; command -v ninja && ninja --version
  nproc
  find "$(python3 -c 'import torch, os; print(os.path.dirname(os.path.dirname(torch.__file__)))')" -name nccl.h 2>/dev/null | head -3
  ls "$(python3 -c 'import torch, os; print(os.path.dirname(torch.__file__))')/include" | tr '\n' ' '; echo
}

stage_build() {
  local torch_prefix gen=()
  torch_prefix=$(python3 -c "import torch; print(torch.utils.cmake_prefix_path)")
  # The same CMake arguments as scripts/setup.sh's CUDA build: prefix, sm_90, NCCL, .carry/root.
  ablenerf_cuda_cmake_args "$torch_prefix" 90
  command -v ninja >/dev/null && gen=(-G Ninja)
  local t0=$SECONDS
  cmake -S . -B build-cuda "${gen[@]}" -DCMAKE_BUILD_TYPE=Release \
    "${ABLENERF_CUDA_CMAKE_ARGS[@]}" > "$OUT/cmake.log" 2>&1 || { tail -40 "$OUT/cmake.log"; return 1; }
  grep -E "c10d|nccl|Gloo|CUDA" "$OUT/cmake.log" | head
  # BUILD_TARGETS (e.g. "ablenerf test_gpu") builds only those; default: everything.
  local targets=()
  for t in ${BUILD_TARGETS:-}; do targets+=(--target "$t"); done
  cmake --build build-cuda -j "$(nproc)" "${targets[@]}" -- $([ ${#gen[@]} -gt 0 ] && echo -k 0 || echo -k) > "$OUT/build.log" 2>&1
  local rc=$?
  echo "build rc $rc in $((SECONDS - t0)) s"
  [ $rc -eq 0 ] || grep -E "error|Error" "$OUT/build.log" | head -40
  # The viewer links Debian's cpp-httplib from .carry/root; should that library not load on this
  # machine, rebuild without the viewer rather than lose the session's other stages.
  if [ -x "$bin" ] && ! "$bin" --version > "$OUT/start.log" 2>&1; then
    echo "build: $bin does not start ($(head -c 300 "$OUT/start.log")); rebuilding with ABLENERF_VIEW=OFF"
    cmake -S . -B build-cuda -DABLENERF_VIEW=OFF >> "$OUT/cmake.log" 2>&1 &&
      cmake --build build-cuda -j "$(nproc)" "${targets[@]}" >> "$OUT/build.log" 2>&1 || rc=1
  fi
  return $rc
}

# The viewer on the GPU: the same requests as docs/BENCHMARKS.md's CPU rows (one render + PNG per
# request, median of 7 timed requests at 32, 100, 128, 400 and 800 pixels square, camera 0's pose) on
# the lego5 stage's run (/tmp/lego5, or VIEW_RUN), and the time from launch to the server answering.
stage_view() {
  local run=${VIEW_RUN:-/tmp/lego5} port=7311 pid rc
  [ -d "$run" ] || { echo "view: no run in $run (run the lego5 stage first)"; return 1; }
  date +%s.%N > "$OUT/view_launch"
  $bin view --run "$run" --port $port --device "${VIEW_DEVICE:-cuda}" > "$OUT/view.log" 2>&1 &
  pid=$!
  python3 - "$port" "$OUT/view_launch" $pid <<'PY'
import json, os, statistics, sys, time, urllib.request
port, launch, pid = int(sys.argv[1]), float(open(sys.argv[2]).read()), int(sys.argv[3])
base = f"http://127.0.0.1:{port}"
while True:
    try:
        cams = json.load(urllib.request.urlopen(base + "/api/cameras", timeout=5)); break
    except OSError:
        os.kill(pid, 0)  # raises when the server ended
        if time.time() - launch > 60: sys.exit("view: no answer in 60 s")
        time.sleep(0.05)
print(f"view: server answering {time.time() - launch:.2f} s after launch")
pose = ",".join(f"{v:.6f}" for v in cams["cameras"][0])
for size in (32, 100, 128, 400, 800):
    times = []
    for i in range(8):
        t = time.perf_counter()
        urllib.request.urlopen(f"{base}/api/render?w={size}&h={size}&pose={pose}", timeout=120).read()
        times.append(time.perf_counter() - t)
    times = sorted(times[1:])  # the first request of a size warms its shapes
    med = statistics.median(times)
    print(f"view: {size}x{size} render + PNG median {med:.3f} s ({1/med:.1f} frames/s), min {times[0]:.3f} max {times[-1]:.3f}")
PY
  rc=$?
  kill $pid 2>/dev/null; wait $pid 2>/dev/null
  [ $rc -eq 0 ] || tail -3 "$OUT/view.log"
  return $rc
}

stage_test() {
  (cd build-cuda && ctest --output-on-failure -j 8 --timeout 900) > "$OUT/ctest.log" 2>&1
  local rc=$?
  tail -15 "$OUT/ctest.log"
  return $rc
}

stage_gputest() {
  # Verbose: GoogleTest's own lines show which tests ran and which skipped (a skip passes ctest).
  (cd build-cuda && ctest -L gpu -V --timeout 600) > "$OUT/ctest_gpu.log" 2>&1
  local rc=$?
  grep -E "tests passed|tests failed|PASSED|SKIPPED|FAILED" "$OUT/ctest_gpu.log" | tail -15
  return $rc
}

# One bench JSON per step size: 1024-ray steps (the release's per-GPU batch) and 8192-ray steps
# (the paper's global batch, micro-batches of 4096), rendering in 16384-ray chunks.
# ablenerf bench on the GPU at the blender preset with the fast settings (bf16, the fused kernels;
# the CUDA graph is the preset's): BINARY RAYS, then bench's other flags (--steps, --matmul, ...).
# Micro-batches of at most 4096 rays.
fast_bench() {
  local b=$1 rays=$2
  shift 2
  "$b" bench --config configs/blender.toml --device cuda --rays "$rays" --micro-batch $((rays < 4096 ? rays : 4096)) \
    --render-rays 16384 --warmup 2 --set compute.precision=bf16 --set compute.attention=fused "$@"
}

stage_bench() {
  local rc=0 rays
  for rays in 1024 8192; do
    fast_bench "$bin" $rays --steps ${BENCH_STEPS:-20} --matmul 8192 --compare > "$OUT/bench_$rays.json" 2> "$OUT/bench_$rays.err" || { rc=1; tail -5 "$OUT/bench_$rays.err"; continue; }
    python3 - "$OUT/bench_$rays.json" <<'PY'
import json, sys
j = json.load(open(sys.argv[1]))
for k in ("reference", "fast"):
    r = j[k]
    print(f"{k:9s} {r['precision']} {r['attention']} graph={r.get('cuda_graph')}: train {r['train']['rays']:.0f}-ray steps "
          f"{r['train']['rays_per_s']:.0f} rays/s (host {1e3*r['train']['cpu_s_median']:.1f} ms/step, "
          f"wall {1e3*r['train']['wall_s_median']:.1f} ms/step), render {r['render']['rays_per_s']:.0f} rays/s = "
          f"{r['render']['seconds_per_image']:.2f} s/800x800, peak {r['peak_memory_bytes']/2**30:.1f} GiB, "
          f"matmul {r['matmul_peak']['flop_per_s']/1e12:.0f} TFLOP/s ({r['matmul_peak']['dtype']}), "
          f"train at {100*r['train']['fraction_of_matmul_peak']:.1f}% of it")
print("speedup", j["speedup"])
PY
  done
  return $rc
}

# Two binaries on the same machine in the same minutes: each round runs both at each step size, in
# turn, so drift in clocks or temperature falls on both; the per-round rates and their medians.
stage_versus() {
  local rc=0 rays round b
  [ -x "${VERSUS_BIN:-}" ] || { echo "versus: VERSUS_BIN (the binary to compare against) is not set or not executable"; return 1; }
  for round in $(seq "${ROUNDS:-3}"); do
    for rays in 1024 8192; do
      for b in "$VERSUS_BIN" "$bin"; do
        fast_bench "$b" $rays --steps ${BENCH_STEPS:-20} --matmul 2048 > "$OUT/versus_${round}_${rays}_$(basename "$b").json" 2> "$OUT/versus.err" || { rc=1; tail -5 "$OUT/versus.err"; }
      done
    done
  done
  python3 - "$OUT" "$(basename "$VERSUS_BIN")" "$(basename "$bin")" <<'PY'
import glob, json, statistics, sys
out, old, new = sys.argv[1:]
for rays in (1024, 8192):
    runs = {b: [json.load(open(f)) for f in sorted(glob.glob(f"{out}/versus_*_{rays}_{b}.json"))] for b in (old, new)}
    rates = {b: [j["train"]["rays_per_s"] for j in v] for b, v in runs.items()}
    render = {b: [j["render"]["seconds_per_image"] for j in v] for b, v in runs.items()}
    m = {b: statistics.median(v) for b, v in rates.items() if v}
    print(f"{rays}-ray steps: " + "; ".join(f"{b} {' '.join(f'{r:.0f}' for r in rates[b])} rays/s (median {m[b]:.0f}, "
          f"render {statistics.median(render[b]):.2f} s/800x800)" for b in (old, new) if rates[b]))
    if len(m) == 2: print(f"  {new} / {old}: {m[new] / m[old]:.3f}")
PY
  return $rc
}

# Where the GPU's time goes: bench --trace on the fast settings (Kineto: the kernels inside the CUDA
# graph's replays too), 1024-ray steps; the trace (for Perfetto) and the report stay in $OUT.
stage_profile() {
  fast_bench "$bin" 1024 --steps ${BENCH_STEPS:-10} --matmul 8192 --trace "$OUT/trace_1024.json" > "$OUT/profile_1024.json" 2> "$OUT/profile_1024.err" || { tail -5 "$OUT/profile_1024.err"; return 1; }
  python3 - "$OUT/profile_1024.json" <<'PY'
import json, sys
t = json.load(open(sys.argv[1]))["trace"]
print(f"host: {t['ops_per_step']:.0f} ops, {t['self_ms_per_step']:.2f} ms self time per step")
g = t.get("gpu")
if not g:
    print("no GPU events in the trace (Kineto/CUPTI unavailable?)"); sys.exit(0)
print(f"gpu: {g['events_per_step']:.0f} kernels/copies per step, busy {g['busy_ms_per_step']:.3f} ms per step")
for k in g["top"]:
    print(f"  {k['ms_per_step']:8.3f} ms {100*k['share']:5.1f}% x{k['calls_per_step']:.0f}  {k['kernel'][:110]}")
PY
}

# Which host op each kernel's time comes from: the eager step (a CUDA graph's replay hides the ops
# that launched its kernels), 3 steps under the profiler, grouped by scripts/gpu_attribute.py.
stage_attribute() {
  fast_bench "$bin" 1024 --steps 3 --matmul 4096 --set train.graph=false --trace "$OUT/trace_eager.json" > "$OUT/attribute.json" 2> "$OUT/attribute.err" || {
    tail -5 "$OUT/attribute.err"; return 1; }
  python3 scripts/gpu_attribute.py "$OUT/trace_eager.json" --steps 3
}

stage_peerbench() {
  local rc=0 rays micro
  for rays in 1024 8192; do
    micro=$((rays < 4096 ? rays : 4096))
    python3 .carry/peer/release_gpu_bench.py .carry/release --rays $rays --micro $micro --variants tf32,bf16 \
      > "$OUT/peer_bench_$rays.jsonl" 2> "$OUT/peer_bench_$rays.err" || { rc=1; tail -5 "$OUT/peer_bench_$rays.err"; }
    cat "$OUT/peer_bench_$rays.jsonl"
  done
  return $rc
}

stage_peertrain() {
  python3 .carry/peer/release_gpu_train.py .carry/release "$lego" --seconds "${BUDGET:-300}" --rays 1024 \
    --test-views 6 --precision tf32 > "$OUT/peer_train.json" 2> "$OUT/peer_train.err"
  local rc=$?
  cat "$OUT/peer_train.json"; [ $rc -eq 0 ] || tail -5 "$OUT/peer_train.err"
  return $rc
}

# ablenerf's budget recipe on lego for the same wall-clock budget, then PSNR on test views 0-5.
stage_lego5() {
  local run=/tmp/lego5 t0=$SECONDS extra=() kv
  for kv in ${LEGO5_SET:-}; do extra+=(--set "$kv"); done
  rm -rf "$run"
  $bin train --data "$lego" --config configs/budget.toml --out "$run" --device cuda \
    --set train.time_budget_s="${BUDGET:-300}" --set train.eval_views=2 "${extra[@]}" > "$OUT/lego5_train.log" 2>&1
  local rc=$?
  echo "lego5: train rc $rc, $((SECONDS - t0)) s wall (data loading included)"
  grep -m2 -E "^(error|internal error)|what\(\)|Error" "$OUT/lego5_train.log" | cut -c1-400
  tail -c 300 "$OUT/lego5_train.log"; echo
  $bin eval --run "$run" --split test --max-images 6 > "$OUT/lego5_eval.log" 2>&1 || { tail -5 "$OUT/lego5_eval.log"; return 1; }
  grep '^eval' "$OUT/lego5_eval.log"
  cp "$run/log.jsonl" "$OUT/lego5_log.jsonl"
  cp "$run/eval/test/metrics.json" "$OUT/lego5_metrics.json"
  return $rc
}


# Real captures on the GPU (docs/GPU.md): each folder of CAPTURES (default the fox at 270x480 that
# scripts/carry.sh makes, and the COLMAP capture `process` made of the same photos) trained for
# CAPTURE_BUDGET seconds (default 120) with configs/budget.toml, then evaluated on its held-out views
# (every 8th image); CAPTURE_SET="k=v ..." adds settings, DEVICE=cpu makes a dry run here. The run of the first stays in /tmp/cap_<name> for the view stage.
stage_capture() {
  local rc=0 entry dir name run t0 extra kv own preset evalopts
  for entry in ${CAPTURES:-.carry/fox4 .carry/fox4_sfm}; do
    dir=${entry%@*} name=$(basename "$entry") name=${name#*@}
    [ -d "$dir" ] || { echo "capture: $dir not carried"; rc=1; continue; }
    own=CAPTURE_SET_$name extra=()
    for kv in ${CAPTURE_SET:-} ${!own:-}; do extra+=(--set "$kv"); done
    preset=CAPTURE_CONFIG_$name preset=${!preset:-${CAPTURE_CONFIG:-configs/budget.toml}}
    evalopts=CAPTURE_EVAL_$name evalopts=${!evalopts:-}
    # fox4_sfm travels without its photos, which are fox4's (scripts/carry.sh).
    [ "$(basename "$dir")" = fox4_sfm ] && [ ! -d "$dir/images" ] && cp -r .carry/fox4/images "$dir/images"
    run=/tmp/cap_$name t0=$SECONDS
    rm -rf "$run"
    echo "capture $name: $dir, $preset ${extra[*]}"
    $bin train --data "$dir" --config "$preset" --out "$run" --device "${DEVICE:-cuda}" \
      --set train.time_budget_s="${CAPTURE_BUDGET:-120}" "${extra[@]}" > "$OUT/cap_${name}_train.log" 2>&1 || {
      rc=1; echo "capture $name: train FAILED"; grep -m3 -E "error|what\(\)" "$OUT/cap_${name}_train.log" | cut -c1-400; continue; }
    echo "capture $name: trained in $((SECONDS - t0)) s wall; $(grep -m1 -iE "unbounded|contract|ndc" "$OUT/cap_${name}_train.log" | cut -c1-200)"
    tail -c 300 "$OUT/cap_${name}_train.log"; echo
    $bin eval --run "$run" $evalopts > "$OUT/cap_${name}_eval.log" 2>&1 || { rc=1; tail -5 "$OUT/cap_${name}_eval.log"; continue; }
    grep '^eval' "$OUT/cap_${name}_eval.log"
    cp "$run/log.jsonl" "$OUT/cap_${name}_log.jsonl"
  done
  return $rc
}

stage_nccl() {
  $bin synth --out /tmp/syn --res 32 --train-views 8 --test-views 2 > /dev/null || return 1
  rm -rf /tmp/nccl_run
  WORLD_SIZE=1 RANK=0 LOCAL_RANK=0 MASTER_ADDR=127.0.0.1 MASTER_PORT=29517 timeout 300 \
    $bin train --data /tmp/syn --config configs/demo.toml --out /tmp/nccl_run --device cuda --dist-backend nccl \
    --set train.steps=30 --set train.eval_every=0 --set train.log_every=10 > "$OUT/nccl.log" 2>&1
  local rc=$?
  echo "nccl one-process run rc $rc"; tail -3 "$OUT/nccl.log"; tail -1 /tmp/nccl_run/log.jsonl
  return $rc
}

# The same short run (seed, batches, schedule) in two compute modes on lego at 400x400.
stage_quality() {
  local steps=${QUALITY_STEPS:-400}
  for mode in "fp32 plain" "bf16 fused"; do
    set -- $mode
    local run=/tmp/q_$1
    rm -rf "$run"
    local t0=$SECONDS
    $bin train --data "$lego" --config configs/blender.toml --out "$run" --device cuda \
      --set data.downscale=2 --set train.steps="$steps" --set train.rays_per_step=4096 --set train.micro_batch=4096 \
      --set train.lr_warmup_steps=100 --set train.lr_decay_steps=0 --set train.eval_every=0 --set train.log_every=50 \
      --set eval.chunk=16384 --set compute.precision=$1 --set compute.attention=$2 > "$OUT/quality_$1.log" 2>&1 || {
      tail -5 "$OUT/quality_$1.log"; return 1; }
    local train_s=$((SECONDS - t0))
    $bin eval --run "$run" --split test --max-images 8 > "$OUT/quality_$1_eval.log" 2>&1 || { tail -5 "$OUT/quality_$1_eval.log"; return 1; }
    echo "$1 $2: $steps steps in ${train_s} s; $(tail -1 "$OUT/quality_$1_eval.log" | head -c 0)$(grep '^eval' "$OUT/quality_$1_eval.log")"
    cp "$run/eval/test/metrics.json" "$OUT/quality_$1_metrics.json"
    cp "$run/log.jsonl" "$OUT/quality_$1_log.jsonl"
  done
}

# Training only (the evaluation is stage lego8eval, to fit the device's 10-minute calls).
stage_lego8() {
  local budget=480 run=/tmp/lego8 steps=${LEGO_STEPS:-}
  # Steps that fit the budget at the bench's training rate (85%: data, logging, held-out checks).
  [ -n "$steps" ] || steps=$(python3 -c "import json; j=json.load(open('/tmp/bench.json')); print(int(0.85*$budget*j['fast']['train']['rays_per_s']/8192))" 2>/dev/null)
  [ -n "$steps" ] || steps=2000
  rm -rf "$run"
  local t0=$SECONDS
  $bin train --data "$lego" --config configs/blender.toml --out "$run" --device cuda --time-limit $budget \
    --set train.steps="$steps" --set train.rays_per_step=8192 --set train.micro_batch=4096 \
    --set train.lr_warmup_steps=$((steps / 20)) --set train.lr_decay_steps=0 \
    --set train.eval_every=$((steps / 4)) --set train.eval_views=2 --set train.log_every=25 \
    --set train.ckpt_every=0 --set eval.chunk=16384 \
    --set compute.precision=bf16 --set compute.attention=fused > "$OUT/lego8_train.log" 2>&1
  local rc=$?
  echo "lego8: train rc $rc, $steps steps planned, $((SECONDS - t0)) s wall (data loading included)"
  tail -c 600 "$OUT/lego8_train.log"; echo
  cp "$run/log.jsonl" "$OUT/lego8_log.jsonl"
  return $rc
}

stage_lego8eval() {
  local run=/tmp/lego8 t0=$SECONDS
  $bin eval --run "$run" --split test --max-images 20 > "$OUT/lego8_eval.log" 2>&1 || { tail -5 "$OUT/lego8_eval.log"; return 1; }
  echo "lego8 eval: $((SECONDS - t0)) s"; grep '^eval' "$OUT/lego8_eval.log"
  cp "$run/log.jsonl" "$OUT/lego8_log.jsonl"
  cp "$run/eval/test/metrics.json" "$OUT/lego8_metrics.json"
  cp "$run/report.html" "$OUT/lego8_report.html"
}

rc=0
for s in "$@"; do
  stamp "$s"
  "stage_$s" || { rc=1; echo "stage $s FAILED"; }
done
stamp done
exit $rc
