#!/usr/bin/env bash
# Builds the libFuzzer targets (clang, ASan + UBSan, coverage) and fuzzes each for N seconds,
# starting from the committed seed corpus in fuzz/corpus/NAME.
#   scripts/fuzz.sh [SECONDS] [TARGET...]     (default: 60 s, every fuzz/fuzz_*.cpp)
# The build is -DABLENERF_FUZZ_ONLY=ON: only the torch-free sources that are fuzzed
# (the image decoders, the dataset json, COLMAP and .npy readers: ablenerf_fuzz_core in
# CMakeLists.txt) and the targets, no LibTorch.
# Environment:
#   ABLENERF_FUZZ_BUILD  build folder (default build-fuzz)
#   ABLENERF_JOBS        build parallelism (default: the number of cores)
#   ABLENERF_FUZZ_PARALLEL  targets fuzzed at once (default: the number of cores)
#   ABLENERF_FUZZ_MERGE=1  afterwards, merge what the run found into fuzz/corpus/NAME (minimised)
# New inputs go to BUILD/fuzz-corpus/NAME, crashes to BUILD/fuzz-artifacts/. Exit status 1 when a
# target crashed, leaked or a sanitizer reported an error.
set -euo pipefail
cd "$(dirname "$0")/.."
secs=${1:-60}
shift || true
build=${ABLENERF_FUZZ_BUILD:-build-fuzz}
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
  for f in fuzz/fuzz_*.cpp; do targets+=("$(basename "$f" .cpp | sed 's/^fuzz_//')"); done
fi

if ! command -v clang++ >/dev/null; then
  echo "fuzz: clang++ not found (Debian: apt-get install -y clang libclang-rt-14-dev)" >&2
  exit 1
fi
start=$SECONDS
# Configured every time (a second or two): a folder left by the older LibTorch-based fuzz build
# is switched over to the torch-free one.
mkdir -p "$build"
cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_COMPILER=clang++ \
  -DABLENERF_FUZZ_ONLY=ON >"$build/fuzz-configure.log" 2>&1 ||
  { cat "$build/fuzz-configure.log" >&2; exit 1; }
cmake --build "$build" -j "${ABLENERF_JOBS:-$(nproc)}" --target "${targets[@]/#/fuzz_}" >"$build/fuzz-build.log" 2>&1 ||
  { tail -30 "$build/fuzz-build.log" >&2; exit 1; }
echo "fuzz: build ${build} took $((SECONDS - start)) s"

# No LibTorch in these binaries, so leaks are findings too.
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}

# One target's run, its summary to stdout when it ends: exit status 1 on a finding.
fuzz_one() {
  local t=$1 found="$build/fuzz-corpus/$1" t_start=$SECONDS
  mkdir -p "$found" "$build/fuzz-artifacts"
  if ! "$build/fuzz_$t" -max_total_time="$secs" -max_len=4096 -timeout=10 -rss_limit_mb=4096 -print_final_stats=1 \
      -artifact_prefix="$build/fuzz-artifacts/$t-" "$found" "fuzz/corpus/$t" >"$build/fuzz-$t.log" 2>&1; then
    echo "fuzz: $t FAILED (log: $build/fuzz-$t.log, inputs: $build/fuzz-artifacts/)" >&2
    grep -E "^fuzz_|ERROR|runtime error|SUMMARY|Test unit written" "$build/fuzz-$t.log" | head -10 >&2
    return 1
  fi
  echo "fuzz: $t ran ${secs}s from fuzz/corpus/$t (new inputs $found, took $((SECONDS - t_start)) s):" \
    "$(grep -E "stat::number_of_executed_units" "$build/fuzz-$t.log" | tail -1 | tr -s ' ')"
  if [ "${ABLENERF_FUZZ_MERGE:-0}" = 1 ]; then
    "$build/fuzz_$t" -merge=1 -max_len=4096 "fuzz/corpus/$t" "$found" >"$build/fuzz-$t-merge.log" 2>&1
  fi
}

# The targets run side by side, ABLENERF_FUZZ_PARALLEL at a time (default: one per core), each for
# the whole of its seconds: the same fuzzing per target as one after another, in less wall time.
parallel=${ABLENERF_FUZZ_PARALLEL:-$(nproc)}
status=0
pids=()
for t in "${targets[@]}"; do
  if [ ${#pids[@]} -ge "$parallel" ]; then
    wait "${pids[0]}" || status=1
    pids=("${pids[@]:1}")
  fi
  fuzz_one "$t" &
  pids+=($!)
done
for p in "${pids[@]}"; do wait "$p" || status=1; done
exit $status
