#!/usr/bin/env bash
# Prepares .carry/ here (Debian bookworm, with the package registry) for a GPU machine that has none
# (docs/GPU.md): the small build dependencies as Debian packages unpacked into .carry/root, and lego's
# train split plus its first 20 test views in .carry/lego when ../shared/data has lego.
# The device tool carries them with `carry: [".carry"]` (64 MiB in all).
set -euo pipefail
cd "$(dirname "$0")/.."
root=.carry/root
lib=$root/usr/lib/x86_64-linux-gnu
rm -rf .carry/debs "$root"
mkdir -p .carry/debs "$root"
# Headers and libraries the build links: CLI, json, toml, tests, Gloo's headers, PNG + zlib, JPEG
# (libjpeg-turbo), and the viewer's cpp-httplib with the headers of what it was built with (OpenSSL,
# Brotli) and Brotli's runtime (the GPU machine's own libssl3 and libz serve at run time).
(cd .carry/debs && apt-get download libcli11-dev nlohmann-json3-dev libtomlplusplus-dev libgtest-dev \
  libgmock-dev googletest libgloo-dev libpng-dev libpng16-16 zlib1g-dev zlib1g \
  libjpeg62-turbo-dev libjpeg62-turbo libcpp-httplib-dev libcpp-httplib0.11 libssl-dev \
  libbrotli-dev libbrotli1)
for f in .carry/debs/*.deb; do dpkg -x "$f" "$root"; done
rm -rf .carry/debs "$root/usr/share/doc" "$root/usr/share/man" "$root/usr/src"
# Static archives are unused (everything links the shared libraries) but GoogleTest's, which
# its CMake package names: ~13 MB of the 64 MiB the device tool carries.
find "$lib" -name '*.a' ! -name 'libgtest*' ! -name 'libgmock*' -delete
# Fix-ups for a root that is not /: the zlib link Debian keeps in /lib, and libjpeg's jconfig.h,
# which Debian keeps in the multiarch folder the compiler searches only under /usr.
ln -sf "../../../lib/x86_64-linux-gnu/$(basename "$(readlink -f "$root/lib/x86_64-linux-gnu/libz.so.1")")" "$lib/libz.so"
cp "$root/usr/include/x86_64-linux-gnu/jconfig.h" "$root/usr/include/"
cp -r "$root/usr/include/x86_64-linux-gnu/openssl/." "$root/usr/include/openssl/"
echo "carry: $(du -sh "$root" | cut -f1) in $root"

lego=../shared/data/nerf_synthetic/lego
if [ -d "$lego" ]; then
  rm -rf .carry/lego && mkdir -p .carry/lego/test
  cp "$lego/transforms_train.json" .carry/lego/ && cp -r "$lego/train" .carry/lego/
  python3 - "$lego" <<'PY'
import json, shutil, sys
src = sys.argv[1]
meta = json.load(open(f"{src}/transforms_test.json"))
meta["frames"] = meta["frames"][:20]
for f in meta["frames"]:
    shutil.copy(f"{src}/{f['file_path']}.png", f".carry/lego/{f['file_path']}.png")
json.dump(meta, open(".carry/lego/transforms_test.json", "w"), indent=1)
PY
  echo "carry: $(du -sh .carry/lego | cut -f1) in .carry/lego"
fi
echo "carry: $(du -sh .carry | cut -f1) in all (the device tool takes 64 MiB; the peer's release and scripts,
  .carry/release and .carry/peer, go in what is left)"
