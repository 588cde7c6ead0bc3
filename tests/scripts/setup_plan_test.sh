#!/usr/bin/env bash
# The build plan of scripts/setup.sh (which LibTorch, which folder) with a stub python3 first on
# PATH standing in for PyTorch: a working CUDA PyTorch 2.x, one older than 2, a failing import,
# and ABLENERF_CPU_ONLY=1. Builds nothing; takes about a second.
#   tests/scripts/setup_plan_test.sh
set -uo pipefail
repo=$(cd "$(dirname "$0")/../.." && pwd)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
failures=0

# stub NAME BODY: a python3 in $tmp/NAME that runs BODY (a shell snippet) whatever it is asked.
stub() {
  mkdir -p "$tmp/$1"
  printf '#!/bin/sh\n%s\n' "$2" >"$tmp/$1/python3"
  chmod +x "$tmp/$1/python3"
}
stub cuda 'echo "cuda-ok 2.11.0+cu130 90 /opt/fake py/torch/share/cmake"'
stub old 'echo "cuda-ok 1.13.1 80 /opt/old/torch/share/cmake"'
stub broken 'echo "Traceback: no module named torch" >&2; exit 1'
stub garbage 'echo "something else entirely"'

# expect NAME STUB "ENV..." "ARGS" LINE...: every LINE must appear in the plan's output.
expect() {
  local name=$1 which=$2 envs=$3 args=$4 out line
  shift 4
  # The plan must come from the probe, not from a plan exported by a calling script.
  out=$(env -u ABLENERF_PLAN_KIND -u ABLENERF_BUILD_DIR -u ABLENERF_CPU_ONLY $envs \
        PATH="$tmp/$which:$PATH" "$repo/scripts/setup.sh" --print-plan $args 2>&1)
  for line in "$@"; do
    if ! grep -qxF -- "$line" <<<"$out"; then
      echo "FAIL $name: expected line '$line' in:"; sed 's/^/    /' <<<"$out"
      failures=$((failures + 1))
      return
    fi
  done
  echo "ok   $name"
}

expect cuda-default cuda "" "" \
  kind=cuda build_dir=build-cuda "torch_prefix=/opt/fake py/torch/share/cmake" cuda_arch=90
expect cuda-explicit-dir cuda "" "my-build" kind=cuda build_dir=my-build
expect cuda-forced-cpu cuda "ABLENERF_CPU_ONLY=1" "" \
  kind=cpu build_dir=build torch_prefix= "why=ABLENERF_CPU_ONLY=1"
expect cpu-only-0-keeps-gpu cuda "ABLENERF_CPU_ONLY=0" "" kind=cuda build_dir=build-cuda
expect torch-older-than-2 old "" "" kind=cpu build_dir=build torch_prefix=
expect no-torch broken "" "" kind=cpu build_dir=build torch_prefix= "why=no PyTorch with a working GPU"
expect unexpected-output garbage "" "" kind=cpu build_dir=build

# ablenerf_build_dir (what demo.sh and test.sh run from) agrees with the plan.
dir=$(env -u ABLENERF_PLAN_KIND -u ABLENERF_BUILD_DIR -u ABLENERF_CPU_ONLY PATH="$tmp/cuda:$PATH" \
      bash -c ". '$repo/scripts/lib.sh' && ablenerf_build_dir")
if [ "$dir" = build-cuda ]; then echo "ok   build-dir-function"; else
  echo "FAIL build-dir-function: got '$dir'"; failures=$((failures + 1)); fi

# A plan exported by a calling script is kept by setup.sh (no second probe: the stub would fail).
out=$(env -u ABLENERF_CPU_ONLY PATH="$tmp/broken:$PATH" ABLENERF_PLAN_KIND=cuda ABLENERF_BUILD_DIR=build-cuda \
      ABLENERF_TORCH_PREFIX=/x ABLENERF_CUDA_ARCH=90 ABLENERF_PLAN_WHY=test "$repo/scripts/setup.sh" --print-plan)
if grep -qxF kind=cuda <<<"$out" && grep -qxF build_dir=build-cuda <<<"$out"; then
  echo "ok   exported-plan-kept"
else
  echo "FAIL exported-plan-kept:"; sed 's/^/    /' <<<"$out"; failures=$((failures + 1))
fi

# The CUDA build's CMake arguments: the prefix, the architecture, and NCCL's own header from pip's
# nvidia-nccl package, not PyTorch's wrapper header of the same name.
site="$tmp/site packages"
mkdir -p "$site/torch/share/cmake" "$site/torch/include/torch/csrc/cuda" "$site/nvidia/nccl/include"
touch "$site/torch/include/torch/csrc/cuda/nccl.h" "$site/nvidia/nccl/include/nccl.h"
args=$(cd "$tmp" && bash -c ". '$repo/scripts/lib.sh' && ablenerf_cuda_cmake_args '$site/torch/share/cmake' 90 &&
       printf '%s\n' \"\${ABLENERF_CUDA_CMAKE_ARGS[@]}\"")
before=$failures
for want in "-DCMAKE_PREFIX_PATH=$site/torch/share/cmake" -DCMAKE_CUDA_ARCHITECTURES=90 \
            "-DNCCL_INCLUDE_DIR=$site/nvidia/nccl/include"; do
  if ! grep -qxF -- "$want" <<<"$args"; then
    echo "FAIL cuda-cmake-args: expected '$want' in:"; sed 's/^/    /' <<<"$args"; failures=$((failures + 1))
  fi
done
[ $failures -eq $before ] && echo "ok   cuda-cmake-args"
# PyTorch's wrapper header alone is not NCCL: no NCCL_INCLUDE_DIR then.
rm -r "$site/nvidia"
args=$(cd "$tmp" && bash -c ". '$repo/scripts/lib.sh' && ablenerf_cuda_cmake_args '$site/torch/share/cmake' 90 &&
       printf '%s\n' \"\${ABLENERF_CUDA_CMAKE_ARGS[@]}\"")
if grep -q -- -DNCCL_INCLUDE_DIR <<<"$args"; then
  echo "FAIL cuda-cmake-args-no-nccl:"; sed 's/^/    /' <<<"$args"; failures=$((failures + 1))
else
  echo "ok   cuda-cmake-args-no-nccl"
fi

if [ $failures -ne 0 ]; then echo "setup_plan_test: $failures failed"; exit 1; fi
echo "setup_plan_test: all passed"
