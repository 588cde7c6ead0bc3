#!/usr/bin/env bash
# Builds the Debian package: scripts/setup.sh's build, then CPack's DEB generator in the build
# folder (CMakeLists.txt, "cpack"). Prints the package's path; `sudo apt-get install ./FILE.deb`
# installs it with its dependencies.
#   scripts/package.sh
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/lib.sh
ablenerf_plan
scripts/setup.sh
build=$ABLENERF_BUILD_DIR
(cd "$build" && cpack -G DEB >cpack.log 2>&1) || { echo "package: cpack failed, see $build/cpack.log" >&2; exit 1; }
deb=$(ls -t "$build"/ablenerf_*.deb | head -1)
echo "package: $deb"
dpkg-deb --info "$deb" | sed -n 's/^ Depends:/package: depends on:/p'
