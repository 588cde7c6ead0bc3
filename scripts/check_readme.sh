#!/usr/bin/env bash
# Runs the README's command blocks, so that its recipes cannot drift from the code.
#   scripts/check_readme.sh [NAME...]      (default: every marked block, in README order)
#   scripts/check_readme.sh --list         names of the marked blocks
# A block is checked when the line before its ```bash fence is `<!-- check: NAME -->`. The blocks
# run in order, each with `bash -e` from the same scratch folder: a copy of the repository made of
# links to its files (the build folder included, so nothing is rebuilt) with its own data/ and
# runs/, so a later block may use what an earlier one wrote and the checkout's own data/ and runs/
# are left alone. A failing block is named with its commands and output; the others still run,
# and the check fails at the end.
# Lines that run scripts/test.sh are skipped: test.sh runs this script, and CI runs test.sh itself
# (.ci/run). Expects a built tree (scripts/setup.sh).
# Environment: ABLENERF_DEMO_STEPS (default here 50) shortens the main job's training, as the
# README says; ABLENERF_CHECK_KEEP=1 keeps the scratch folder.
set -euo pipefail
cd "$(dirname "$0")/.."
repo=$PWD
. scripts/lib.sh

# Prints the marked blocks as records: a line "@@ NAME", then the block's lines.
extract() {
  awk '
    /^<!-- check: [A-Za-z0-9_.-]+ -->[ \t]*$/ { name = $3; armed = 1; next }
    armed && /^```bash[ \t]*$/ { print "@@ " name; inblock = 1; armed = 0; next }
    inblock && /^```[ \t]*$/ { inblock = 0; next }
    inblock { print; next }
    armed && !/^[ \t]*$/ { print "check_readme: marker for " name " is not followed by a ```bash block" > "/dev/stderr"; exit 1 }
  ' README.md
}

names=$(extract | sed -n 's/^@@ //p')
if [ "${1:-}" = --list ]; then echo "$names"; exit 0; fi
if [ -z "$names" ]; then echo "check_readme: no marked blocks in README.md" >&2; exit 1; fi
if [ $# -gt 0 ]; then
  for want in "$@"; do
    grep -qxF "$want" <<<"$names" || { echo "check_readme: no block named '$want' (have: $(echo $names))" >&2; exit 1; }
  done
  names=$(printf '%s\n' "$@")
fi

# The scratch copy: a link for every top-level entry but data/ and runs/; `build` is the folder
# the scripts use here (build, or build-cuda with a CUDA PyTorch), so `build/ablenerf` resolves.
build=$(ablenerf_build_dir)
[ -x "$build/ablenerf" ] || { echo "check_readme: $build/ablenerf is missing: run scripts/setup.sh first" >&2; exit 1; }
scratch=$(mktemp -d "${TMPDIR:-/tmp}/ablenerf_readme.XXXXXX")
[ "${ABLENERF_CHECK_KEEP:-0}" = 1 ] || trap 'rm -rf "$scratch"' EXIT
for entry in * .ci .carry; do
  case $entry in data | runs | build) continue ;; esac
  [ -e "$entry" ] && ln -s "$repo/$entry" "$scratch/$entry"
done
ln -sfn "$repo/$build" "$scratch/build"
[ -e "$scratch/$build" ] || ln -s "$repo/$build" "$scratch/$build"

export ABLENERF_DEMO_STEPS=${ABLENERF_DEMO_STEPS:-50}
start=$SECONDS
failed=()
while read -r name; do
  block=$(extract | awk -v n="$name" '/^@@ / { on = ($2 == n); next } on')
  script=$scratch/.check_$name.sh
  {
    echo "set -eo pipefail"
    grep -vE '^[[:space:]]*scripts/test\.sh([[:space:]]|$)' <<<"$block" || true
  } >"$script"
  t0=$SECONDS
  echo "check_readme: $name ..."
  rc=0
  (cd "$scratch" && bash "$script" </dev/null) >"$scratch/.check_$name.log" 2>&1 || rc=$?
  if [ $rc -ne 0 ]; then
    echo "check_readme: README block '$name' FAILED (exit $rc, $((SECONDS - t0)) s); its commands:" >&2
    sed 's/^/    /' <<<"$block" >&2
    echo "  its output (last 30 lines; progress bars split at carriage returns):" >&2
    tr '\r' '\n' <"$scratch/.check_$name.log" | grep -v '^[[:space:]]*$' | tail -30 | sed 's/^/    /' >&2
    failed+=("$name")
    continue
  fi
  echo "check_readme: $name ok ($((SECONDS - t0)) s)"
done <<<"$names"
# The skipped test line is CI's own command.
grep -q "scripts/test.sh" .ci/run || { echo "check_readme: .ci/run does not run scripts/test.sh" >&2; failed+=(.ci/run); }
if [ ${#failed[@]} -gt 0 ]; then
  echo "check_readme: FAILED: ${failed[*]} ($((SECONDS - start)) s)" >&2
  exit 1
fi
echo "check_readme: all README blocks ran ($((SECONDS - start)) s, ABLENERF_DEMO_STEPS=$ABLENERF_DEMO_STEPS)"
