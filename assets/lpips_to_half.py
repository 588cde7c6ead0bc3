#!/usr/bin/env python3
"""Makes assets/lpips_alex_v0.1.pt from the float32 original (assets/LPIPS_WEIGHTS.md).

    python3 assets/lpips_to_half.py ORIGINAL.pt assets/lpips_alex_v0.1.pt

Standard library only (no PyTorch needed). The original is a torch.save archive: a zip holding
DIR/data.pkl (a pickled dict name -> tensor whose storages are `torch.FloatStorage`, each with its
element count) and one raw little-endian float32 record DIR/data/KEY per storage. The copy keeps
every record name, the dictionary, the shapes and the strides; it only
  * names `torch.HalfStorage` instead of `torch.FloatStorage` in data.pkl (element counts are
    unchanged, so nothing else in the pickle moves), and
  * rewrites each storage record as float16, rounded to nearest, ties to even (as LibTorch's
    .to(torch::kHalf); a value outside float16's range stops the conversion).
Records are stored uncompressed with a fixed timestamp, so the output is byte-for-byte reproducible.
"""
import pickletools
import struct
import sys
import zipfile

FLOAT = b"ctorch\nFloatStorage\n"
HALF = b"ctorch\nHalfStorage\n"


def storage_globals(pickle_bytes):
    """The `torch.*Storage` globals the pickle names."""
    return {arg for op, arg, _ in pickletools.genops(pickle_bytes)
            if op.name in ("GLOBAL", "STACK_GLOBAL") and arg and "Storage" in str(arg)}


def main(src, dst):
    with zipfile.ZipFile(src) as zin:
        infos = zin.infolist()
        pkl_name = next(i.filename for i in infos if i.filename.endswith("/data.pkl"))
        root = pkl_name[: -len("data.pkl")]
        pkl = zin.read(pkl_name)
        if storage_globals(pkl) != {"torch FloatStorage"} or pkl.count(FLOAT) != 1:
            sys.exit(f"{src}: expected every storage to be one memoised torch.FloatStorage")
        half_pkl = pkl.replace(FLOAT, HALF)
        assert storage_globals(half_pkl) == {"torch HalfStorage"}

        with zipfile.ZipFile(dst, "w", compression=zipfile.ZIP_STORED) as zout:
            for info in infos:
                data = zin.read(info.filename)
                if info.filename == pkl_name:
                    data = half_pkl
                elif info.filename.startswith(root + "data/"):
                    n = len(data) // 4
                    data = struct.pack(f"<{n}e", *struct.unpack(f"<{n}f", data))
                out = zipfile.ZipInfo(info.filename, date_time=(1980, 1, 1, 0, 0, 0))
                out.compress_type = zipfile.ZIP_STORED
                out.external_attr = 0o644 << 16
                zout.writestr(out, data)


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])
