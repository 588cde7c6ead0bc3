#!/usr/bin/env bash
# Installs the Debian packages ablenerf needs (only the missing ones) and builds it.
# Re-running it when nothing changed takes seconds.
#   scripts/setup.sh [BUILD_DIR]      build (default: build-cuda or build, below)
#   scripts/setup.sh --print-plan     print which LibTorch and folder it would use; build nothing
# The LibTorch (scripts/lib.sh, ablenerf_plan): when python3 imports a PyTorch >= 2 whose CUDA
# works, its CUDA LibTorch, built into build-cuda for the GPU's architecture; otherwise Debian's
# CPU LibTorch (libtorch-dev) in build. ABLENERF_CPU_ONLY=1 forces the CPU build.
# Environment: ABLENERF_SKIP_APT=1 skips the package step; ABLENERF_JOBS sets build parallelism;
# ABLENERF_CMAKE_ARGS adds CMake arguments. Without a package registry (apt-get missing or failing),
# the package step warns and goes on: the build then says what, if anything, is missing.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/lib.sh

print_plan=0
if [ "${1:-}" = --print-plan ]; then print_plan=1; shift; fi
ablenerf_plan "${1:-}"
build_dir=$ABLENERF_BUILD_DIR
if [ $print_plan = 1 ]; then
  echo "kind=$ABLENERF_PLAN_KIND"
  echo "build_dir=$build_dir"
  echo "torch_prefix=$ABLENERF_TORCH_PREFIX"
  echo "cuda_arch=$ABLENERF_CUDA_ARCH"
  echo "why=$ABLENERF_PLAN_WHY"
  exit 0
fi

packages=(
  g++ cmake make ninja-build pkg-config     # Ninja keeps both cores busy through the unity build
  libcli11-dev nlohmann-json3-dev libtomlplusplus-dev libpng-dev libjpeg-dev
  libsleef-dev                            # vector erf / exp for the CPU kernels (kernels/gelu_cpu.h)
  libgloo-dev                             # headers for c10d's Gloo backend (multi-process training)
  libgtest-dev libgmock-dev
  ffmpeg                                  # MP4 output of `ablenerf render`
  libcpp-httplib-dev                      # the web viewer (`ablenerf view`)
  libopen3d-dev                           # geometry out (`ablenerf export --points / --mesh`)
  clang libclang-rt-14-dev                # libFuzzer + ASan/UBSan runtimes (fuzz smoke run in scripts/test.sh)
  clang-format                            # the C++ format check (scripts/format.sh --check in scripts/test.sh)
)
# Tensors and autograd: Debian's LibTorch and the fast BLAS it should use (the CUDA build uses
# the LibTorch inside PyTorch instead).
[ "$ABLENERF_PLAN_KIND" = cpu ] && packages+=(libtorch-dev libopenblas0-pthread)

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
    if ! command -v apt-get >/dev/null ||
       ! timeout 300 "${sudo_cmd[@]}" apt-get update -qq ||
       ! timeout 900 "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null; then
      echo "setup: warning: could not install ${missing[*]} (no apt-get or no package registry);" \
           "building with what is present" >&2
    fi
  fi
fi

jobs=${ABLENERF_JOBS:-$(nproc)}
if [ ! -f "$build_dir/CMakeCache.txt" ]; then
  cmake_args=(-DCMAKE_BUILD_TYPE=Release)
  command -v ninja >/dev/null && cmake_args+=(-G Ninja)
  if [ "$ABLENERF_PLAN_KIND" = cuda ]; then
    ablenerf_cuda_cmake_args "$ABLENERF_TORCH_PREFIX" "$ABLENERF_CUDA_ARCH"
    cmake_args+=("${ABLENERF_CUDA_CMAKE_ARGS[@]}")
  fi
  mkdir -p "$build_dir"
  # shellcheck disable=SC2086
  if ! cmake -S . -B "$build_dir" "${cmake_args[@]}" ${ABLENERF_CMAKE_ARGS:-} >"$build_dir/cmake.log" 2>&1; then
    tail -30 "$build_dir/cmake.log" >&2
    echo "setup: configure failed (full log: $build_dir/cmake.log)" >&2
    exit 1
  fi
fi
echo "setup: $(ablenerf_torch_summary "$build_dir"), building in $build_dir with $jobs jobs" \
     "($ABLENERF_PLAN_WHY; log: $build_dir/build.log)"
build_start=$SECONDS
if ! cmake --build "$build_dir" -j "$jobs" >"$build_dir/build.log" 2>&1; then
  grep -E "error|Error" "$build_dir/build.log" | head -40 >&2
  echo "setup: build failed (full log: $build_dir/build.log)" >&2
  exit 1
fi
echo "setup: ok ($build_dir/ablenerf; build step $((SECONDS - build_start)) s)"
