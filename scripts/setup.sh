#!/usr/bin/env bash
# Installs the Debian packages ablenerf needs (only the missing ones) and builds it.
# Re-running it when nothing changed takes seconds.
#   scripts/setup.sh [BUILD_DIR]      (default: build)
# Environment: ABLENERF_SKIP_APT=1 skips the package step; ABLENERF_JOBS sets build parallelism;
# ABLENERF_CMAKE_ARGS adds CMake arguments (e.g. -DCMAKE_PREFIX_PATH=... for a CUDA LibTorch).
set -euo pipefail
cd "$(dirname "$0")/.."
build_dir=${1:-build}

packages=(
  g++ cmake make pkg-config
  libtorch-dev libopenblas0-pthread       # tensors, autograd; the fast BLAS it should use
  libcli11-dev nlohmann-json3-dev libtomlplusplus-dev libpng-dev
  libgloo-dev                             # headers for c10d's Gloo backend (multi-process training)
  libgtest-dev libgmock-dev libbenchmark-dev
  ffmpeg                                  # MP4 output of `ablenerf render`
  clang libclang-rt-14-dev                # libFuzzer + ASan/UBSan runtimes (fuzz smoke run in scripts/test.sh)
)

if [ "${ABLENERF_SKIP_APT:-0}" != 1 ]; then
  missing=()
  for p in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  if [ ${#missing[@]} -gt 0 ]; then
    echo "setup: installing ${missing[*]}"
    sudo_cmd=()
    [ "$(id -u)" -ne 0 ] && sudo_cmd=(sudo)
    export DEBIAN_FRONTEND=noninteractive
    "${sudo_cmd[@]}" apt-get update -qq
    "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  fi
fi

jobs=${ABLENERF_JOBS:-$(nproc)}
if [ ! -f "$build_dir/CMakeCache.txt" ]; then
  # shellcheck disable=SC2086
  cmake -S . -B "$build_dir" -DCMAKE_BUILD_TYPE=Release ${ABLENERF_CMAKE_ARGS:-} >/dev/null
fi
echo "setup: building in $build_dir with $jobs jobs (log: $build_dir/build.log)"
if ! cmake --build "$build_dir" -j "$jobs" >"$build_dir/build.log" 2>&1; then
  grep -E "error|Error" "$build_dir/build.log" | head -40 >&2
  echo "setup: build failed (full log: $build_dir/build.log)" >&2
  exit 1
fi
echo "setup: ok ($build_dir/ablenerf)"
