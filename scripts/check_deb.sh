#!/usr/bin/env bash
# The Debian package on a machine that has nothing else: a minimal Debian bookworm made with
# debootstrap in a temporary folder, the package installed there by apt (which brings its
# dependencies from Debian's archive), then, from an empty folder inside it, `ablenerf --version`,
# `synth`, `train --preset demo` for 1,500 steps (a minute; a run much earlier has no surfaces to
# export), `eval` (LPIPS from the installed copy), `render` (a video through ffmpeg) and `export`
# (a mesh and points). Then the photos path with COLMAP (a suggested package, installed by apt
# next): 120 photos of `synth --scene room` posed by `process`, trained on with `--preset capture`
# for 300 steps, evaluated.
# Needs root (debootstrap, chroot), debootstrap, and a package: scripts/package.sh makes one.
#   scripts/check_deb.sh [build/ablenerf_VERSION_amd64.deb]   (about five minutes, most of it apt and COLMAP)
set -euo pipefail
cd "$(dirname "$0")/.."
deb=${1:-$(ls -t build*/ablenerf_*.deb 2>/dev/null | head -1)}
[ -n "$deb" ] && [ -f "$deb" ] || { echo "check_deb: no package (run scripts/package.sh first)" >&2; exit 2; }
command -v debootstrap >/dev/null || { echo "check_deb: needs debootstrap (apt-get install debootstrap)" >&2; exit 1; }
root=$(mktemp -d /tmp/ablenerf-deb.XXXXXX)
cleanup() { umount "$root/proc" 2>/dev/null || true; rm -rf "$root" "$root.log"; }
trap cleanup EXIT
echo "check_deb: a minimal bookworm in $root"
debootstrap --variant=minbase bookworm "$root" http://deb.debian.org/debian >"$root.log" 2>&1 ||
  { echo "check_deb: debootstrap failed, see $root.log" >&2; exit 1; }
cp /etc/resolv.conf "$root/etc/resolv.conf"
mount -t proc proc "$root/proc"
cp "$deb" "$root/root/"
name=$(basename "$deb")
chroot "$root" /bin/bash -c "apt-get -o APT::Sandbox::User=root update -q >/dev/null && DEBIAN_FRONTEND=noninteractive \
  apt-get -o APT::Sandbox::User=root install -y -q /root/$name >/root/apt.log 2>&1" || { echo "check_deb: apt-get install failed:" >&2;
  tail -20 "$root/root/apt.log" >&2; exit 1; }
chroot "$root" /bin/bash -euc '
  mkdir /root/empty && cd /root/empty
  ablenerf --version
  ablenerf synth --out scene --quiet
  ablenerf train --data scene --preset demo --out run --steps 1500 --quiet 2>/dev/null
  ablenerf eval --run run --json | grep -q "\"lpips\"" && echo "check_deb: eval with LPIPS ran"
  test -f run/report.html
  ablenerf render --run run --path orbit --frames 8 --out run/orbit.mp4 --quiet
  test -s run/orbit.mp4 && echo "check_deb: render wrote an mp4 (ffmpeg, a recommended package)"
  ablenerf export --run run --mesh run/mesh.ply --points run/points.ply --quiet
  test -s run/mesh.ply && test -s run/points.ply && echo "check_deb: export wrote a mesh and points"'
chroot "$root" /bin/bash -c "DEBIAN_FRONTEND=noninteractive apt-get -o APT::Sandbox::User=root install -y -q colmap \
  >/root/apt_colmap.log 2>&1" || { echo "check_deb: apt-get install colmap failed:" >&2;
  tail -20 "$root/root/apt_colmap.log" >&2; exit 1; }
chroot "$root" /bin/bash -euc '
  cd /root/empty
  ablenerf synth --scene room --out room --res 200 --train-views 120 --test-views 2 --quiet
  ablenerf process --images room/train --out capture --threads 2 2>/dev/null | grep -q "\"registered\"" &&
    echo "check_deb: process posed the photos with COLMAP"
  ablenerf train --data capture --preset capture --downscale 1 --out cap_run --steps 300 --quiet 2>/dev/null
  ablenerf eval --run cap_run --json | grep -q "\"psnr\"" && echo "check_deb: the capture trained and evaluated"'
echo "check_deb: $name installs with apt on a bare bookworm and runs synth, process, train, eval, render, export"
