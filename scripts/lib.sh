# Shell functions shared by the scripts (sourced, not run). Kept free of side effects: sourcing
# only defines functions.
#
# Which LibTorch builds ablenerf, and into which folder:
#   * a PyTorch >= 2 whose CUDA works (python3 imports torch, torch.cuda.is_available()) and
#     ABLENERF_CPU_ONLY != 1: that PyTorch's LibTorch, folder build-cuda;
#   * otherwise Debian's CPU LibTorch (libtorch-dev), folder build.
# `scripts/setup.sh --print-plan` prints the decision without building (tests/scripts/).

# The Python probe: one line "cuda-ok VERSION ARCH PREFIX" (ARCH: compute capability as 90;
# PREFIX: torch.utils.cmake_prefix_path, last so that it may contain spaces), or a non-zero exit.
ablenerf_probe_torch() {
  command -v python3 >/dev/null 2>&1 || return 1
  python3 -c '
import torch
assert torch.cuda.is_available()
major, minor = torch.cuda.get_device_capability()
print("cuda-ok", torch.__version__, f"{major}{minor}", torch.utils.cmake_prefix_path)
' 2>/dev/null
}

# ablenerf_plan [BUILD_DIR]: sets and exports
#   ABLENERF_PLAN_KIND    cuda | cpu
#   ABLENERF_BUILD_DIR    BUILD_DIR when given, else build-cuda (cuda) or build (cpu)
#   ABLENERF_TORCH_PREFIX the CUDA PyTorch's cmake prefix ("" for cpu)
#   ABLENERF_CUDA_ARCH    its GPU's compute capability, e.g. 90 ("" for cpu)
#   ABLENERF_PLAN_WHY     one phrase: why this kind
# A plan already exported by a calling script (ABLENERF_PLAN_KIND set) is kept, so that
# demo.sh/test.sh and the setup.sh they call agree without probing twice.
ablenerf_plan() {
  local want_dir=${1:-}
  if [ -z "${ABLENERF_PLAN_KIND:-}" ]; then
    ABLENERF_PLAN_KIND=cpu ABLENERF_TORCH_PREFIX="" ABLENERF_CUDA_ARCH=""
    if [ "${ABLENERF_CPU_ONLY:-0}" = 1 ]; then
      ABLENERF_PLAN_WHY="ABLENERF_CPU_ONLY=1"
    else
      local line tag ver arch prefix
      if line=$(ablenerf_probe_torch) && read -r tag ver arch prefix <<<"$line" &&
         [ "$tag" = cuda-ok ] && [ -n "$prefix" ]; then
        if [ "${ver%%.*}" -ge 2 ] 2>/dev/null; then
          ABLENERF_PLAN_KIND=cuda ABLENERF_TORCH_PREFIX=$prefix ABLENERF_CUDA_ARCH=$arch
          ABLENERF_PLAN_WHY="PyTorch $ver with a working GPU (sm_$arch)"
        else
          ABLENERF_PLAN_WHY="PyTorch $ver with a GPU is older than 2"
        fi
      else
        ABLENERF_PLAN_WHY="no PyTorch with a working GPU"
      fi
    fi
    ABLENERF_BUILD_DIR=""
  fi
  if [ -n "$want_dir" ]; then
    ABLENERF_BUILD_DIR=$want_dir
  elif [ -z "${ABLENERF_BUILD_DIR:-}" ]; then
    if [ "$ABLENERF_PLAN_KIND" = cuda ]; then ABLENERF_BUILD_DIR=build-cuda; else ABLENERF_BUILD_DIR=build; fi
  fi
  export ABLENERF_PLAN_KIND ABLENERF_BUILD_DIR ABLENERF_TORCH_PREFIX ABLENERF_CUDA_ARCH ABLENERF_PLAN_WHY
}

# ablenerf_build_dir: the folder the scripts build into and run from (build or build-cuda).
ablenerf_build_dir() {
  ablenerf_plan
  echo "$ABLENERF_BUILD_DIR"
}

# ablenerf_cuda_cmake_args TORCH_PREFIX ARCH: sets the array ABLENERF_CUDA_CMAKE_ARGS, the CMake
# arguments of a build against a PyTorch's CUDA LibTorch: its prefix, the GPU architecture, NCCL's
# header from pip's nvidia-nccl package when present, and the small dependencies carried in
# .carry/root on machines without a package registry (docs/GPU.md). Run from the repository root.
ablenerf_cuda_cmake_args() {
  local prefix=$1 arch=${2:-native} root=$PWD/.carry/root site nccl_h
  local prefixes=$prefix
  [ -d "$root/usr" ] && prefixes="$prefix;$root/usr"
  ABLENERF_CUDA_CMAKE_ARGS=(-DCMAKE_PREFIX_PATH="$prefixes" -DCMAKE_CUDA_ARCHITECTURES="$arch")
  # prefix = .../site-packages/torch/share/cmake: NCCL's own header is in pip's nvidia-nccl package
  # under .../site-packages (not torch/csrc/cuda/nccl.h, PyTorch's wrapper of the same name).
  site=$(dirname "$(dirname "$(dirname "$prefix")")")
  nccl_h=$(find "$site" -path '*/nccl/include/nccl.h' 2>/dev/null | head -1)
  [ -n "$nccl_h" ] && ABLENERF_CUDA_CMAKE_ARGS+=(-DNCCL_INCLUDE_DIR="$(dirname "$nccl_h")")
  if [ -d "$root/usr" ]; then
    local lib=$root/usr/lib/x86_64-linux-gnu
    ABLENERF_CUDA_CMAKE_ARGS+=(
      -DPNG_LIBRARY="$lib/libpng16.so" -DPNG_PNG_INCLUDE_DIR="$root/usr/include"
      -DZLIB_LIBRARY="$lib/libz.so" -DZLIB_INCLUDE_DIR="$root/usr/include"
      -DJPEG_LIBRARY="$lib/libjpeg.so" -DJPEG_INCLUDE_DIR="$root/usr/include")
    # The viewer's cpp-httplib, when scripts/carry.sh unpacked it (the headers must match the library).
    if [ -f "$lib/libcpp-httplib.so" ]; then
      ABLENERF_CUDA_CMAKE_ARGS+=(
        -DHTTPLIB_LIBRARY="$lib/libcpp-httplib.so" -DHTTPLIB_INCLUDE_DIR="$root/usr/include"
        -DOPENSSL_SSL_INCLUDE_DIR="$root/usr/include")
    fi
  fi
}

# The LibTorch a configured build folder uses, in one phrase: "LibTorch 2.11.0 (CUDA) from DIR".
ablenerf_torch_summary() {
  local cache=$1/CMakeCache.txt torch_dir version kind=CPU
  torch_dir=$(sed -n 's/^Torch_DIR:PATH=//p' "$cache" 2>/dev/null)
  version=$(sed -n 's/^set(PACKAGE_VERSION "\(.*\)")$/\1/p' "$torch_dir/TorchConfigVersion.cmake" 2>/dev/null)
  grep -q '^C10_CUDA_LIBRARY:FILEPATH=/' "$cache" 2>/dev/null && kind=CUDA
  echo "LibTorch ${version:-?} ($kind) from ${torch_dir:-?}"
}
