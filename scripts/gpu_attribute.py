#!/usr/bin/env python3
"""The GPU time of a Kineto trace (`ablenerf bench --trace`, best of an eager step: train.graph=false)
grouped by the host operators that launched each kernel: for every kernel, the innermost
autograd node or ablenerf stage on the launching thread and the ATen op under it.

  scripts/gpu_attribute.py TRACE.json[.gz] [--steps N] [--top K]

A kernel launched inside a CUDA graph's replay is attributed to the replay alone, so the eager trace
is the one that names its sources (scripts/gpu.sh, stage attribute)."""
import argparse
import bisect
import collections
import gzip
import json


def load(path):
    opener = gzip.open if path.endswith(".gz") else open
    with opener(path, "rt") as f:
        t = json.load(f)
    return t["traceEvents"] if isinstance(t, dict) else t


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("trace")
    ap.add_argument("--steps", type=float, default=1.0, help="steps in the trace: figures per step")
    ap.add_argument("--top", type=int, default=25)
    a = ap.parse_args()
    ev = load(a.trace)
    launches = {e["args"]["correlation"]: e for e in ev
                if e.get("cat") in ("cuda_runtime", "cuda_driver") and "correlation" in e.get("args", {})}
    ops = collections.defaultdict(list)  # thread -> host ops sorted by start, outer before inner
    for e in ev:
        if e.get("cat") in ("cpu_op", "user_annotation") and e.get("ph") == "X":
            ops[e["tid"]].append(e)
    starts, parents = {}, {}
    for tid, lst in ops.items():
        lst.sort(key=lambda e: (e["ts"], -e["dur"]))
        starts[tid] = [e["ts"] for e in lst]
        # Each op's parent (the innermost op still open where it starts; -1 for none), by one pass
        # with a stack: host ops on one thread nest.
        par, stack = [], []
        for j, e in enumerate(lst):
            while stack and lst[stack[-1]]["ts"] + lst[stack[-1]]["dur"] < e["ts"]:
                stack.pop()
            par.append(stack[-1] if stack else -1)
            stack.append(j)
        parents[tid] = par

    def enclosing(launch):
        """Every op open at the launch, outermost first: up from the last op that started before it."""
        lst, st, par = ops.get(launch["tid"], []), starts.get(launch["tid"], []), parents.get(launch["tid"], [])
        j = bisect.bisect_right(st, launch["ts"]) - 1
        while j >= 0 and lst[j]["ts"] + lst[j]["dur"] < launch["ts"]:
            j = par[j]
        chain = []
        while j >= 0:
            chain.append(lst[j])
            j = par[j]
        return chain[::-1]

    def source(chain):
        node = next((e["name"] for e in reversed(chain)
                     if e["name"].startswith("autograd::engine::evaluate_function: ")
                     or e["name"].startswith("ablenerf.")), "(no node)")
        node = node.replace("autograd::engine::evaluate_function: ", "backward ")
        aten = next((e["name"] for e in chain if e["name"].startswith(("aten::", "ablenerf::"))), "")
        return f"{node} > {aten}" if aten else node

    total = collections.defaultdict(lambda: [0, 0.0])
    busy = 0.0
    for e in ev:
        if e.get("cat") not in ("kernel", "gpu_memcpy", "gpu_memset"):
            continue
        busy += e["dur"]
        launch = launches.get(e.get("args", {}).get("correlation"))
        key = source(enclosing(launch)) if launch else "(no launch found)"
        total[key][0] += 1
        total[key][1] += e["dur"]
    print(f"gpu busy {busy / 1e3 / a.steps:.3f} ms per step")
    for key, (n, us) in sorted(total.items(), key=lambda kv: -kv[1][1])[:a.top]:
        print(f"{us / 1e3 / a.steps:8.3f} ms {100 * us / busy:5.1f}% x{n / a.steps:<5.0f} {key[:120]}")


if __name__ == "__main__":
    main()
