#!/usr/bin/env bash
# scripts/zoo.sh on a zoo of two tiny synthetic captures (one per half) and one missing capture, a
# few steps each: the table lists all three (the missing one as missing), each trained capture's
# figures come from its own eval and log, and each half has its mean; --speed scales the steps and
# the preset's data.auto_passes together, and is refused where it cannot.
#   tests/scripts/zoo_test.sh BINARY      (ctest's zoo_table)
set -euo pipefail
repo=$(cd "$(dirname "$0")/../.." && pwd)
bin=${1:?binary}
work=$(mktemp -d "${TMPDIR:-/tmp}/ablenerf_zoo.XXXXXX")
trap 'rm -rf "$work"' EXIT
fail() { echo "zoo_test: $*" >&2; exit 1; }
"$bin" synth --out "$work/caps/a" --res 32 --train-views 6 --test-views 2 --seed 1 --quiet
"$bin" synth --out "$work/caps/b" --res 32 --train-views 6 --test-views 2 --seed 2 --quiet
cat >"$work/zoo.txt" <<ZOO
# a comment line
alpha  tune     a
beta   confirm  b   --downscale 2
gamma  confirm  not_there
ZOO
ABLENERF_BIN=$bin "$repo/scripts/zoo.sh" --zoo "$work/zoo.txt" --captures "$work/caps" --out "$work/out" \
  --steps 4 --set train.eval_every=0 demo >"$work/zoo.log" 2>&1 || { cat "$work/zoo.log" >&2; fail "zoo.sh failed"; }
[ -f "$work/out/table.md" ] || fail "no table.md"
python3 - "$work/out" <<'PY' || exit 1
import json, sys
out = sys.argv[1]
t = json.load(open(f"{out}/table.json"))
caps = {r["capture"]: r for r in t["captures"]}
assert list(caps) == ["alpha", "beta", "gamma"], list(caps)
assert caps["gamma"].get("missing") is True, caps["gamma"]
for name in ("alpha", "beta"):
    r = caps[name]
    m = json.load(open(f"{out}/{name}/eval/test/metrics.json"))["mean"]
    assert abs(r["psnr"] - m["psnr"]) < 1e-9, (name, r, m)
    assert r["steps"] == 4, r
cfg = open(f"{out}/beta/config.toml").read()
assert "downscale = 2" in cfg, "the zoo file's extra flags did not reach train"
# 4 steps of the demo preset's rays over 6 views of 32 x 32 (alpha) and of 16 x 16 (beta).
rays = 256
assert abs(caps["alpha"]["passes_per_pixel"] - 4 * rays / (6 * 32 * 32)) < 1e-9, caps["alpha"]
assert abs(caps["beta"]["passes_per_pixel"] - 4 * rays / (6 * 16 * 16)) < 1e-9, caps["beta"]
assert t["means"]["tune"]["captures"] == 1 and t["means"]["confirm"]["captures"] == 1, t["means"]
assert abs(t["means"]["confirm"]["psnr"] - caps["beta"]["psnr"]) < 1e-9
table = open(f"{out}/table.md").read()
assert "| gamma | confirm | missing" in table and "mean, confirm" in table, table
PY
# --speed: a screen at equal training time trains N x R steps with the preset's data.auto_passes x R.
passes=$(python3 -c 'import sys, tomllib; print(tomllib.load(open(sys.argv[1], "rb"))["data"]["auto_passes"])' \
  "$repo/configs/capture.toml")
ABLENERF_BIN=$bin "$repo/scripts/zoo.sh" --zoo "$work/zoo.txt" --captures "$work/caps" --out "$work/fast" \
  --half tune --steps 8 --speed 0.5 capture >"$work/fast.log" 2>&1 || { cat "$work/fast.log" >&2; fail "--speed failed"; }
python3 - "$work/fast" "$passes" <<'PY' || exit 1
import json, sys, tomllib
out, passes = sys.argv[1], float(sys.argv[2])
t = json.load(open(f"{out}/table.json"))
assert [r["capture"] for r in t["captures"]] == ["alpha"], t["captures"]
assert t["captures"][0]["steps"] == 4, t["captures"][0]
cfg = tomllib.load(open(f"{out}/alpha/config.toml", "rb"))
assert abs(cfg["data"]["auto_passes"] - passes * 0.5) < 1e-6 * passes, cfg["data"]
PY
# ... and is refused without --steps, with a speed that is not a positive number, and for a preset
# whose images are not sized from its steps.
for bad in "--speed 0.5 capture" "--steps 8 --speed -1 capture" "--steps 8 --speed x capture" "--steps 8 --speed 0.5 demo"; do
  # shellcheck disable=SC2086  # the case's words
  if ABLENERF_BIN=$bin "$repo/scripts/zoo.sh" --zoo "$work/zoo.txt" --captures "$work/caps" --out "$work/bad" \
    $bad >"$work/bad.log" 2>&1; then fail "zoo.sh $bad was accepted"; fi
  grep -q "^zoo: .*--speed" "$work/bad.log" || { cat "$work/bad.log" >&2; fail "zoo.sh $bad: no line naming --speed"; }
done
echo "zoo_test: the zoo's table is right for two tiny captures and a missing one; --speed scales steps and passes"
