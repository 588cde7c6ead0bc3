#!/usr/bin/env bash
# The project's C++ format (.clang-format: Google style at 120 columns, includes left as written).
#   scripts/format.sh          formats every tracked C++ and CUDA file in place
#   scripts/format.sh --check  changes nothing; lists the files that differ and exits 1 if any
# Needs clang-format (Debian's, which scripts/setup.sh installs); clang-format 14 is what the tree
# was formatted with.
set -euo pipefail
cd "$(dirname "$0")/.."
mode=${1:-}
if ! command -v clang-format >/dev/null; then
  echo "format: clang-format not found (scripts/setup.sh installs it; or apt-get install clang-format)" >&2
  exit 1
fi
mapfile -t files < <(git ls-files '*.cpp' '*.h' '*.cu' '*.cuh')
if [ "$mode" = --check ]; then
  bad=()
  for f in "${files[@]}"; do
    clang-format --style=file "$f" | cmp -s - "$f" || bad+=("$f")
  done
  if [ ${#bad[@]} -gt 0 ]; then
    printf 'format: %s differs from .clang-format (run scripts/format.sh)\n' "${bad[@]}" >&2
    exit 1
  fi
  echo "format: ${#files[@]} files match .clang-format"
else
  clang-format --style=file -i "${files[@]}"
  echo "format: formatted ${#files[@]} files"
fi
