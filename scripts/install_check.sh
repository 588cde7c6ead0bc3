#!/usr/bin/env bash
# The installed tree on its own: `cmake --install BUILD` into a temporary prefix, then, in an empty
# folder, the installed binary makes a small demo scene, trains the demo preset for a few steps and
# evaluates it with LPIPS read from the installed weights (not the source tree's).
#   scripts/install_check.sh [BUILD]     (default: the build folder the scripts use)
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/lib.sh
build=${1:-$(ablenerf_build_dir)}
work=$(mktemp -d "${TMPDIR:-/tmp}/ablenerf_install.XXXXXX")
trap 'rm -rf "$work"' EXIT
prefix=$work/prefix
cmake --install "$build" --prefix "$prefix" >"$work/install.log"
bin=$prefix/bin/ablenerf
for f in "$bin" "$prefix/share/ablenerf/assets/lpips_alex_v0.1.pt" "$prefix/share/ablenerf/configs/capture.toml" \
  "$prefix/share/doc/ablenerf/LICENSE"; do
  [ -e "$f" ] || { echo "install_check: $f was not installed" >&2; exit 1; }
done
mkdir "$work/empty"
cd "$work/empty"
"$bin" --version
"$bin" synth --out scene --res 64 --train-views 6 --test-views 2 --seed 1 --quiet
"$bin" train --data scene --preset demo --out run --set train.steps=5 --set train.time_budget_s=0 --quiet
"$bin" eval --run run --quiet
weights=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["lpips_weights"] or "")' run/eval/test/metrics.json)
case $weights in
  "$prefix"/share/ablenerf/assets/*) ;;
  *) echo "install_check: eval read LPIPS from '$weights', not the installed tree" >&2; exit 1 ;;
esac
lpips=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["mean"].get("lpips"))' run/eval/test/metrics.json)
case $lpips in
  "" | None | nan) echo "install_check: eval gave no LPIPS ($lpips)" >&2; exit 1 ;;
esac
echo "install_check: the installed tree trains and evaluates on its own ($prefix)"
