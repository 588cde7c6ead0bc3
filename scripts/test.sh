#!/usr/bin/env bash
# The test command: installs what is missing, builds, runs every test with ctest.
set -euo pipefail
cd "$(dirname "$0")/.."
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-2}
scripts/setup.sh build
cd build
ctest --output-on-failure --timeout 900 -j "${ABLENERF_TEST_JOBS:-1}"
