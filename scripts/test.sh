#!/usr/bin/env bash
# The test command: installs what is missing, checks the C++ format (scripts/format.sh --check),
# builds, runs every test with ctest, runs the
# README's command blocks (scripts/check_readme.sh, under a minute), then a libFuzzer smoke run (30 s
# per target, the targets side by side: scripts/fuzz.sh) when clang and its fuzzer runtime are present.
# Builds into build-cuda where a PyTorch with working CUDA is present, else build (scripts/setup.sh).
# Environment: ABLENERF_FUZZ_SECONDS (per target, default 30; 0 skips the smoke run);
# ABLENERF_README_CHECK=0 skips the README check.
set -euo pipefail
cd "$(dirname "$0")/.."
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-2}

# CUDA compile check: every kernel file (src/kernels/*_cuda.cu) includes only CUDA headers and its
# launch header, so nvcc alone compiles it, without LibTorch or a GPU: a CUDA error fails here in
# seconds. The files compile side by side. Skipped where the CUDA toolkit is absent.
nvcc_bin=$(command -v nvcc || { [ -x /usr/local/cuda/bin/nvcc ] && echo /usr/local/cuda/bin/nvcc; } || true)
if [ -n "$nvcc_bin" ]; then
  nvcc_start=$SECONDS
  pids=() files=() failed=0
  for cu in src/kernels/*_cuda.cu; do
    [ -e "$cu" ] || continue
    "$nvcc_bin" -std=c++17 -O2 -arch=sm_90 -Isrc -c -o /dev/null "$cu" &
    pids+=($!) files+=("$cu")
  done
  for i in "${!pids[@]}"; do
    wait "${pids[$i]}" || { echo "test: nvcc failed on ${files[$i]}"; failed=1; }
  done
  echo "test: nvcc compile check of ${#files[@]} CUDA kernel files took $((SECONDS - nvcc_start)) s"
  [ "$failed" = 0 ] || exit 1
else
  echo "test: nvcc compile check skipped (no CUDA toolkit: nvcc not on PATH)"
fi

. scripts/lib.sh
ablenerf_plan   # the build folder, shared with setup.sh and check_readme.sh
tests/scripts/setup_plan_test.sh   # setup.sh's choice of LibTorch and folder (stub python3; a second)
scripts/setup.sh
# The format check (.clang-format), once setup.sh has installed clang-format. Where it could not
# (a machine without a package registry) the check is skipped with a note, not failed.
if command -v clang-format >/dev/null; then
  scripts/format.sh --check
else
  echo "test: format check skipped (clang-format not installed)"
fi
# Programs only some tests need, from Debian: Chromium for the viewer's headless-browser test
# (tests/view/browser_test.cpp) and COLMAP for `process` on photos rendered by the test
# (tests/cli/process_cli_test.cpp). Each test skips without its program; a failed install leaves
# those tests skipped, not the run failed.
optional=()
command -v chromium >/dev/null || optional+=(chromium)
command -v colmap >/dev/null || optional+=(colmap)
if [ ${#optional[@]} -gt 0 ] && [ "${ABLENERF_SKIP_APT:-0}" != 1 ] && command -v apt-get >/dev/null; then
  sudo_cmd=()
  [ "$(id -u)" -ne 0 ] && sudo_cmd=(sudo)
  echo "test: installing ${optional[*]} (the viewer's browser test, process with COLMAP)"
  DEBIAN_FRONTEND=noninteractive timeout 900 "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${optional[@]}" \
    >/dev/null 2>&1 || echo "test: warning: ${optional[*]} not installed; the tests that need them will be skipped" >&2
fi
(cd "$ABLENERF_BUILD_DIR" && ctest --output-on-failure --timeout 900 -j "${ABLENERF_TEST_JOBS:-1}")
if [ "${ABLENERF_README_CHECK:-1}" != 0 ]; then
  scripts/check_readme.sh
else
  echo "test: README check skipped (ABLENERF_README_CHECK=0)"
fi

# Fuzz smoke stage: builds the torch-free fuzz targets in build-fuzz (clang, ASan + UBSan; about a
# minute from scratch) and fuzzes each from its committed corpus. A finding fails the script.
fuzz_secs=${ABLENERF_FUZZ_SECONDS:-30}
have_fuzzer_runtime() {
  dpkg-query -W -f='${Status}' libclang-rt-14-dev 2>/dev/null | grep -q "install ok installed"
}
if [ "$fuzz_secs" = 0 ]; then
  echo "test: fuzz smoke run skipped (ABLENERF_FUZZ_SECONDS=0)"
elif command -v clang++ >/dev/null && have_fuzzer_runtime; then
  fuzz_start=$SECONDS
  scripts/fuzz.sh "$fuzz_secs"
  echo "test: fuzz smoke stage (build + fuzzing) took $((SECONDS - fuzz_start)) s"
else
  echo "test: fuzz smoke run skipped (needs clang++ and libclang-rt-14-dev: scripts/setup.sh installs them)"
fi
