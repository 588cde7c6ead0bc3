#!/usr/bin/env bash
# The main job, end to end on the embedded demo scene:
# install what is missing, build, render the scene, train the demo preset, evaluate, write the report.
#   scripts/demo.sh [RUN_DIR]   (default: runs/demo)
set -euo pipefail
cd "$(dirname "$0")/.."
run=${1:-runs/demo}
scripts/setup.sh build
# Every core: training and rendering split each batch of rays across the CPU threads
# (compute.cpu_split = "rays"); on the 2-core reference machine that trained the demo model
# 1.75-2.1x faster than one thread (docs/BENCHMARKS.md, "Demo-scene training").
bin=build/ablenerf
data=data/demo
if [ ! -f "$data/transforms_train.json" ]; then
  $bin synth --out "$data" --res 100 --train-views 100 --test-views 20 --seed 0
fi
$bin info --data "$data" >/dev/null
resume=()
[ -f "$run/checkpoint.pt" ] && resume=(--resume)
$bin train --data "$data" --config configs/demo.toml --out "$run" "${resume[@]}"
$bin eval --run "$run" --split test
echo "demo: report at $run/report.html"
