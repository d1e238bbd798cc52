"""Where a cold JIT compile goes, by numba compiler pass.

    LUCENT_CACHE_DIR=$(mktemp -d) .venv/bin/python -m bench.compile_passes [--top 25]

Renders ``examples/cornell_box.json`` at 1 spp with ``lucent render`` in this process, with an empty
cache (give it a fresh ``LUCENT_CACHE_DIR``, or it only loads the kernels), under numba's
``numba:run_pass`` event recorder, and prints the longest passes (pass, function): a pass's time
includes the compiles it starts (typing ``render_rows`` compiles the kernels it calls). Then the
same by self time (a pass's own, the passes it started taken off), per function and summed per
pass. Record results in docs/performance.md ("Start-up").
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--top", type=int, default=25)
    args = parser.parse_args()
    from numba.core import event

    from services.cli import main as lucent

    with tempfile.TemporaryDirectory() as tmp, event.install_recorder("numba:run_pass") as rec:
        t0 = time.perf_counter()
        lucent(["render", "examples/cornell_box.json", "--spp", "1", "-o", f"{tmp}/x.npy", "-q"])
        total = time.perf_counter() - t0
    # numba's passes nest (a compile started while typing a caller runs inside its pass), in
    # this one thread: a stack of the open ones gives each its self time
    passes, own, open_ = [], [], []
    typed: dict[str, int] = {}  # type inferences per function: one per signature compiled
    for ts, ev in rec.buffer:
        key = (ev.data["name"], ev.data.get("qualname"))
        if ev.is_start:
            open_.append([key, ts, 0.0])
            if key[0].startswith("nopython_type_inference"):
                typed[key[1]] = typed.get(key[1], 0) + 1
        else:
            k, start, nested = open_.pop()
            assert k == key, (k, key)
            passes.append((ts - start, key))
            own.append((ts - start - nested, key))
            if open_:
                open_[-1][2] += ts - start
    print(f"lucent render --spp 1: {total:.1f} s in all")
    print("longest passes (a pass's time includes the compiles it started):")
    for seconds, (name, qualname) in sorted(passes, reverse=True)[:args.top]:
        print(f"{seconds:7.2f} s  {name:<32} {qualname}")
    print("by self time:")
    for seconds, (name, qualname) in sorted(own, reverse=True)[:args.top]:
        print(f"{seconds:7.2f} s  {name:<32} {qualname}")
    by_pass: dict[str, float] = {}
    for seconds, (name, _) in own:
        name = name.split(" [")[0]  # numba names a pass "pass [function]"
        by_pass[name] = by_pass.get(name, 0.0) + seconds
    print(f"self time summed by pass ({sum(by_pass.values()):.1f} s in passes):")
    for name, seconds in sorted(by_pass.items(), key=lambda kv: -kv[1])[:12]:
        print(f"{seconds:7.2f} s  {name}")
    print("functions typed more than once (one compile a signature):",
          ", ".join(f"{q} {n}" for q, n in sorted(typed.items(), key=lambda kv: -kv[1])
                    if n > 1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
