#!/usr/bin/env bash
# Trains and evaluates a preset on the capture zoo (zoo/captures.txt) and writes one table: for each
# capture PSNR / SSIM / LPIPS on its held-out views (every 8th photo), steps, passes per training
# pixel and seconds, then each half's mean.
#   scripts/zoo.sh [options] PRESET [BUDGET]
#     PRESET             a preset name (--preset) or a config file (.toml)
#     BUDGET             training time per capture (--time-budget: 15m, 90s, ...; default: the preset's)
#   --half tune|confirm|all   which captures (default all)
#   --captures DIR     the folder holding the zoo's captures (default: captures)
#   --zoo FILE         the zoo (default zoo/captures.txt)
#   --out DIR          runs and the table (default runs/zoo/PRESET)
#   --set KEY=VALUE    passed to every `train` (repeatable): the change being judged
#   --steps N          train N steps instead of a budget: the same work whatever the machine's speed,
#                      the image sizes those of the budget that plans as many rays (N = budget x the
#                      preset's data.auto_rays_per_s / train.rays_per_step: 6855 for the capture
#                      preset's 3 minutes); give no BUDGET with it
#   --speed R          with --steps: a screen at equal training time for a change that runs at R
#                      times the preset's rays per second (`ablenerf bench` on both): N x R steps,
#                      and the preset's data.auto_passes x R, so that the images keep the sizes of
#                      the preset's N-step screen
# Writes OUT/table.md and OUT/table.json; a capture whose folder is missing is listed as missing. One
# training at a time: the figures are only comparable with nothing else running.
set -euo pipefail
repo=$(cd "$(dirname "$0")/.." && pwd)
. "$repo/scripts/lib.sh"
half=all captures=captures zoo=$repo/zoo/captures.txt out="" steps="" speed=""
sets=()
while [ $# -gt 0 ]; do
  case $1 in
    --half) half=$2; shift 2 ;;
    --captures) captures=$2; shift 2 ;;
    --zoo) zoo=$2; shift 2 ;;
    --out) out=$2; shift 2 ;;
    --set) sets+=(--set "$2"); shift 2 ;;
    --steps) steps=$2; shift 2 ;;
    --speed) speed=$2; shift 2 ;;
    -h | --help) sed -n '2,22p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    -*) echo "zoo: unknown option $1" >&2; exit 2 ;;
    *) break ;;
  esac
done
[ $# -ge 1 ] || { echo "zoo: usage: scripts/zoo.sh [options] PRESET [BUDGET] (--help)" >&2; exit 2; }
preset=$1 budget=${2:-}
case $half in tune | confirm | all) ;; *) echo "zoo: --half must be tune, confirm or all" >&2; exit 2 ;; esac
[ -f "$zoo" ] || { echo "zoo: $zoo: missing" >&2; exit 2; }
bin=${ABLENERF_BIN:-$repo/$(cd "$repo" && ablenerf_build_dir)/ablenerf}
[ -x "$bin" ] || { echo "zoo: $bin is missing: run scripts/setup.sh first" >&2; exit 1; }
if [[ $preset == *.toml ]]; then
  preset_args=(--config "$preset") name=$(basename "$preset" .toml) toml=$preset
else
  preset_args=(--preset "$preset") name=$preset toml=$repo/configs/$preset.toml
fi
passes=""
if [ -n "$speed" ]; then
  # N x R steps, and the preset's data.auto_passes x R so that the images keep their sizes.
  [ -n "$steps" ] || { echo "zoo: --speed needs --steps" >&2; exit 2; }
  scaled=$(python3 - "$toml" "$steps" "$speed" <<'PY'
import sys, tomllib
toml, steps, speed = sys.argv[1], int(sys.argv[2]), sys.argv[3]
try:
    r = float(speed)
except ValueError:
    r = 0
if not r > 0: sys.exit(f"zoo: --speed must be a positive number, got {speed}")
passes = tomllib.load(open(toml, "rb")).get("data", {}).get("auto_passes")
if passes is None: sys.exit(f"zoo: --speed: {toml} sets no data.auto_passes (its images are not sized from the steps)")
print(max(1, round(steps * r)), f"{passes * r:.6g}")
PY
  ) || exit 2
  read -r steps passes <<<"$scaled"
fi
out=${out:-runs/zoo/$name}
mkdir -p "$out"
length=()
[ -n "$budget" ] && length=(--time-budget "$budget")
[ -n "$steps" ] && length=(--steps "$steps" --set train.time_budget_s=0)
[ -n "$passes" ] && length+=(--set data.auto_passes="$passes")

rows=$out/rows.jsonl
: >"$rows"
while read -r cap cap_half folder extra; do
  [[ -z $cap || $cap == \#* ]] && continue
  [ "$half" = all ] || [ "$half" = "$cap_half" ] || continue
  data=$captures/$folder run=$out/$cap
  if [ ! -d "$data" ]; then
    printf '{"capture":"%s","half":"%s","missing":true}\n' "$cap" "$cap_half" >>"$rows"
    echo "zoo: $cap: $data missing (docs/CAPTURES.md makes it)" >&2
    continue
  fi
  rm -rf "$run"
  t0=$SECONDS
  # shellcheck disable=SC2086  # the zoo file's extra flags split into words
  "$bin" train --data "$data" "${preset_args[@]}" --out "$run" "${length[@]}" "${sets[@]}" $extra --quiet
  "$bin" eval --run "$run" --quiet
  python3 - "$run" "$cap" "$cap_half" $((SECONDS - t0)) >>"$rows" <<'PY'
import json, sys
run, cap, half, seconds = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
m = json.load(open(f"{run}/eval/test/metrics.json"))["mean"]
cov = [json.loads(l) for l in open(f"{run}/log.jsonl") if '"coverage"' in l]
c = cov[-1] if cov else {}
print(json.dumps({"capture": cap, "half": half, "psnr": m.get("psnr"), "ssim": m.get("ssim"), "lpips": m.get("lpips"),
                  "steps": c.get("step"), "passes_per_pixel": c.get("passes_per_pixel"), "seconds": seconds}))
PY
  echo "zoo: $cap done ($((SECONDS - t0)) s)" >&2
done <"$zoo"

label=${budget:-default}
python3 - "$rows" "$out" "$name" "$label" <<'PY'
import json, sys
rows_file, out, preset, budget = sys.argv[1:5]
rows = [json.loads(l) for l in open(rows_file) if l.strip()]
fmt = lambda v, d: "-" if v is None else f"{v:.{d}f}"
lines = [f"# Zoo: preset {preset}, budget {budget if budget != 'default' else 'the preset' + chr(39) + 's'}", "",
         "| capture | half | PSNR | SSIM | LPIPS | steps | passes per pixel | seconds |",
         "|---|---|---|---|---|---|---|---|"]
for r in rows:
    if r.get("missing"):
        lines.append(f"| {r['capture']} | {r['half']} | missing | | | | | |")
        continue
    lines.append(f"| {r['capture']} | {r['half']} | {fmt(r['psnr'], 2)} | {fmt(r['ssim'], 3)} | {fmt(r['lpips'], 3)} | "
                 f"{r['steps']} | {fmt(r['passes_per_pixel'], 2)} | {r['seconds']} |")
means = {}
for h in ("tune", "confirm"):
    done = [r for r in rows if r["half"] == h and not r.get("missing") and r.get("psnr") is not None]
    if done:
        # A figure a capture lacks (LPIPS of images under its network's smallest size) leaves its mean out.
        mean = lambda k: None if any(r[k] is None for r in done) else sum(r[k] for r in done) / len(done)
        means[h] = {k: mean(k) for k in ("psnr", "ssim", "lpips")}
        means[h]["captures"] = len(done)
        lines.append(f"| **mean, {h}** ({len(done)}) | | {fmt(means[h]['psnr'], 2)} | {fmt(means[h]['ssim'], 3)} | "
                     f"{fmt(means[h]['lpips'], 3)} | | | |")
open(f"{out}/table.md", "w").write("\n".join(lines) + "\n")
json.dump({"preset": preset, "budget": budget, "captures": rows, "means": means}, open(f"{out}/table.json", "w"), indent=1)
print("\n".join(lines))
PY
echo "zoo: table at $out/table.md"
