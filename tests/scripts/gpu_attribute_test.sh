#!/usr/bin/env bash
# scripts/gpu_attribute.py on a hand-made Kineto trace of two steps: each kernel's time goes to the
# innermost autograd node or stage around the host call that launched it (runtime or driver
# launches, matched by correlation id), a launch after the node's last op ended goes to the node,
# copies count too, and a kernel whose launch is not in the
# trace is listed as such; per-step figures divide by --steps.
#   tests/scripts/gpu_attribute_test.sh      (ctest's gpu_attribute)
set -euo pipefail
repo=$(cd "$(dirname "$0")/../.." && pwd)
work=$(mktemp -d "${TMPDIR:-/tmp}/ablenerf_attr.XXXXXX")
trap 'rm -rf "$work"' EXIT
python3 - "$work/trace.json" <<'PY'
import json, sys
ev = []
def op(name, ts, dur, cat="cpu_op", tid=1):
    ev.append({"ph": "X", "cat": cat, "name": name, "ts": ts, "dur": dur, "tid": tid, "pid": 1})
def launch(ts, corr, cat="cuda_runtime", tid=1):
    ev.append({"ph": "X", "cat": cat, "name": "cudaLaunchKernel", "ts": ts, "dur": 1, "tid": tid, "pid": 1,
               "args": {"correlation": corr}})
def kernel(name, dur, corr, cat="kernel"):
    ev.append({"ph": "X", "cat": cat, "name": name, "ts": 10000 + corr, "dur": dur, "tid": 7, "pid": 0,
               "args": {"correlation": corr}})
for step in range(2):
    t0 = 1000 * step
    # backward of a linear layer: its bias sum (300 us) and a product (100 us) launched by the driver
    op("autograd::engine::evaluate_function: AddmmBackward0", t0 + 0, 100)
    op("aten::sum", t0 + 10, 20)
    launch(t0 + 15, 10 * step + 1)
    kernel("reduce_kernel", 300, 10 * step + 1)
    op("aten::mm", t0 + 40, 20)
    launch(t0 + 45, 10 * step + 2, cat="cuda_driver")
    kernel("gemm", 100, 10 * step + 2)
    # launched by the node itself after its last op ended: the node alone
    launch(t0 + 80, 10 * step + 5)
    kernel("fill", 25, 10 * step + 5)
    # a forward stage (a user annotation) with a copy under it
    op("ablenerf.ab_transformer", t0 + 200, 100, cat="user_annotation")
    op("aten::copy_", t0 + 210, 10)
    launch(t0 + 212, 10 * step + 3)
    kernel("Memcpy DtoD", 50, 10 * step + 3, cat="gpu_memcpy")
    # a kernel whose launch the trace lost
    kernel("orphan", 50, 10 * step + 4)
json.dump({"traceEvents": ev}, open(sys.argv[1], "w"))
PY
python3 "$repo/scripts/gpu_attribute.py" "$work/trace.json" --steps 2 > "$work/out.txt"
cat "$work/out.txt"
python3 - "$work/out.txt" <<'PY'
import re, sys
lines = open(sys.argv[1]).read().splitlines()
assert lines[0] == "gpu busy 0.525 ms per step", lines[0]
rows = {}
for l in lines[1:]:
    m = re.match(r"\s*([\d.]+) ms\s+([\d.]+)% x(\d+)\s+(.*)$", l)
    assert m, l
    rows[m.group(4).strip()] = (float(m.group(1)), float(m.group(2)), int(m.group(3)))
want = {
    "backward AddmmBackward0 > aten::sum": (0.300, 57.1, 1),
    "backward AddmmBackward0 > aten::mm": (0.100, 19.0, 1),
    "ablenerf.ab_transformer > aten::copy_": (0.050, 9.5, 1),
    "(no launch found)": (0.050, 9.5, 1),
    "backward AddmmBackward0": (0.025, 4.8, 1),
}
assert rows == want, rows
assert list(rows)[0] == "backward AddmmBackward0 > aten::sum", "largest first"
PY
echo "gpu_attribute_test: ok"
