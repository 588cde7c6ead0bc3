#!/usr/bin/env bash
# Prepares .carry/ here (Debian bookworm, with the package registry) for a GPU machine that has none
# (docs/GPU.md): the small build dependencies as Debian packages unpacked into .carry/root, and lego's
# train split plus its first LEGO_TEST_VIEWS (default 6) test views in .carry/lego when the optional ../shared/data has
# lego, the fox (docs/CAPTURES.md) at a quarter of its size in .carry/fox4 when captures/fox50 (under the checkout, or beside it) is there,
# and LLFF's horns and the scuba-diving video in .carry/horns and .carry/scodive when captures/ has them.
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
  rm -rf .carry/lego && mkdir -p .carry/lego/test .carry/lego/train
  # Two of every three train views (67 of 100, 29 MB): with all 100 (43 MB) the whole carry came to
  # 66.1 MB on 2026-11-26 and the device tool refused it. LEGO_TRAIN_KEEP_ALL=1 carries all 100.
  python3 - "$lego" "${LEGO_TEST_VIEWS:-6}" "${LEGO_TRAIN_KEEP_ALL:-0}" <<'PY'
import json, shutil, sys
src = sys.argv[1]
train = json.load(open(f"{src}/transforms_train.json"))
train["frames"] = [f for i, f in enumerate(train["frames"]) if sys.argv[3] == "1" or i % 3 != 2]
for f in train["frames"]:
    shutil.copy(f"{src}/{f['file_path']}.png", f".carry/lego/{f['file_path']}.png")
json.dump(train, open(".carry/lego/transforms_train.json", "w"), indent=1)
meta = json.load(open(f"{src}/transforms_test.json"))
meta["frames"] = meta["frames"][:int(sys.argv[2])]
for f in meta["frames"]:
    shutil.copy(f"{src}/{f['file_path']}.png", f".carry/lego/{f['file_path']}.png")
json.dump(meta, open(".carry/lego/transforms_test.json", "w"), indent=1)
PY
  echo "carry: $(du -sh .carry/lego | cut -f1) in .carry/lego"
fi
# A real capture (unbounded, OpenCV lens) small enough to travel: fox50's 50 photos at 270x480, the
# intrinsics scaled with them (Pillow, on this machine only: `pip install pillow`).
fox=captures/fox50; [ -d "$fox" ] || fox=../captures/fox50
if [ -d "$fox" ] && python3 -c "import PIL" 2>/dev/null; then
  rm -rf .carry/fox4 && mkdir -p .carry/fox4/images
  python3 - "$fox" <<'PY'
import json, sys
from PIL import Image
src, s = sys.argv[1], 4
meta = json.load(open(f"{src}/transforms.json"))
for k in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
    meta[k] = meta[k] / s
for f in meta["frames"]:
    im = Image.open(f"{src}/{f['file_path']}")
    im.resize((im.width // s, im.height // s), Image.BOX).save(f".carry/fox4/{f['file_path']}", quality=92)
json.dump(meta, open(".carry/fox4/transforms.json", "w"), indent=1)
PY
  echo "carry: $(du -sh .carry/fox4 | cut -f1) in .carry/fox4"
  # The same photos posed by `ablenerf process` (COLMAP), for training a process output there. Its
  # images/ copy stays here (2 MB of the 64 MiB): gpu.sh's capture stage copies .carry/fox4/images back.
  if [ -x build/ablenerf ] && command -v colmap >/dev/null; then
    rm -rf .carry/fox4_sfm
    build/ablenerf process --images .carry/fox4/images --out .carry/fox4_sfm > /dev/null
    rm -rf .carry/fox4_sfm/images .carry/fox4_sfm/database.db .carry/fox4_sfm/colmap.log
    echo "carry: $(du -sh .carry/fox4_sfm | cut -f1) in .carry/fox4_sfm"
  fi
fi
# Two LLFF captures of the zoo (docs/CAPTURES.md), small as JPEG: LLFF's horns at 1/8 (504x378, its
# images_8/) and the scuba-diving phone video at 1/4 (480x270 in images_4/, which capture_gpu reads).
if python3 -c "import PIL" 2>/dev/null; then
  # name : capture folder : its photos : reduced by : the folder written
  for entry in horns:horns_llff:images_8:1:images_8 scodive:scodive_img4831:images:4:images_4; do
    IFS=: read -r name dir sub s outsub <<< "$entry"
    src=captures/$dir; [ -d "$src" ] || src=../captures/$dir
    [ -d "$src/$sub" ] || continue
    out=.carry/$name/$outsub
    rm -rf ".carry/$name" && mkdir -p "$out" && cp "$src/poses_bounds.npy" ".carry/$name/"
    python3 - "$src/$sub" "$out" "$s" <<'PY'
import os, sys
from PIL import Image
src, out, s = sys.argv[1], sys.argv[2], int(sys.argv[3])
for f in sorted(os.listdir(src)):
    im = Image.open(os.path.join(src, f)).convert("RGB")
    im.resize((im.width // s, im.height // s), Image.BOX).save(os.path.join(out, os.path.splitext(f)[0] + ".jpg"), quality=93)
PY
    echo "carry: $(du -sh ".carry/$name" | cut -f1) in .carry/$name"
  done
fi
echo "carry: $(du -sh .carry | cut -f1) in all (the device tool takes 64 MiB; the peer's release and scripts,
  .carry/release and .carry/peer, go in what is left)"
