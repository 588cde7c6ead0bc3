#!/usr/bin/env bash
# The main job, end to end on the embedded demo scene:
# install what is missing, build, render the scene, train the demo preset, evaluate, write the report.
#   scripts/demo.sh [RUN_DIR]   (default: runs/demo)
# Environment: ABLENERF_DEMO_STEPS=N trains N steps instead of the preset's 460 s budget (the learning-rate
# schedule still completes: configs/demo.toml); scripts/check_readme.sh uses 50 to keep CI short.
# ABLENERF_CPU_ONLY=1: the CPU build even where a CUDA PyTorch is present (scripts/setup.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
run=${1:-runs/demo}
. scripts/lib.sh
ablenerf_plan   # build-cuda with a PyTorch whose CUDA works, else build (scripts/lib.sh)
scripts/setup.sh
# Every core: training and rendering split each batch of rays across the CPU threads
# (compute.cpu_split = "rays"); on the 2-core reference machine that trained the demo model
# 1.75-2.1x faster than one thread (docs/benchmarks/history.md, "Demo-scene training"). With a CUDA
# build, --device auto (the default) trains and renders on the GPU.
bin=$ABLENERF_BUILD_DIR/ablenerf
data=data/demo
if [ ! -f "$data/transforms_train.json" ]; then
  $bin synth --out "$data" --res 100 --train-views 100 --test-views 20 --seed 0
fi
$bin info --data "$data" >/dev/null
resume=()
[ -f "$run/checkpoint.pt" ] && resume=(--resume)
steps=()
[ -n "${ABLENERF_DEMO_STEPS:-}" ] && steps=(--set "train.steps=$ABLENERF_DEMO_STEPS")
$bin train --data "$data" --config configs/demo.toml --out "$run" "${resume[@]}" "${steps[@]}"
$bin eval --run "$run" --split test
echo "demo: report at $run/report.html"
