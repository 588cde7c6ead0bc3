#!/usr/bin/env bash
# The main job, end to end on the embedded demo scene:
# install what is missing, build, render the scene, train the demo preset, evaluate, write the report.
#   scripts/demo.sh [RUN_DIR]   (default: runs/demo)
set -euo pipefail
cd "$(dirname "$0")/.."
run=${1:-runs/demo}
scripts/setup.sh build   # before the thread setting below: nproc follows OMP_NUM_THREADS
# One thread unless told otherwise: the demo model's tensors are small, and on the 2-core reference
# machine two OpenMP threads (spin-waiting between ops) ran at ~0.6x the speed of one
# (docs/BENCHMARKS.md, "Demo-scene training").
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
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
