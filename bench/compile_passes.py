"""Where a cold JIT compile goes, by numba compiler pass.

    LUCENT_CACHE_DIR=$(mktemp -d) .venv/bin/python -m bench.compile_passes [--top 25]

Renders ``examples/cornell_box.json`` at 1 spp with ``lucent render`` in this process, with an empty
cache (give it a fresh ``LUCENT_CACHE_DIR``, or it only loads the kernels), under numba's
``numba:run_pass`` event recorder, and prints the longest passes (pass, function): a pass's time
includes the compiles it starts (typing ``render_row`` compiles the kernels it calls). Set
``LUCENT_NUMBA_FAST_INLINE=0`` to see numba's own inliner (renderer/numba_inline.py). Record
results in docs/performance.md ("Start-up").
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

    from renderer.cli import main as lucent

    with tempfile.TemporaryDirectory() as tmp, event.install_recorder("numba:run_pass") as rec:
        t0 = time.perf_counter()
        lucent(["render", "examples/cornell_box.json", "--spp", "1", "-o", f"{tmp}/x.npy", "-q"])
        total = time.perf_counter() - t0
    starts: dict[tuple, list[float]] = {}
    passes = []
    for ts, ev in rec.buffer:
        key = (ev.data["name"], ev.data.get("qualname"))
        if ev.is_start:
            starts.setdefault(key, []).append(ts)
        else:
            passes.append((ts - starts[key].pop(), key))
    passes.sort(reverse=True)
    print(f"lucent render --spp 1: {total:.1f} s in all")
    for seconds, (name, qualname) in passes[:args.top]:
        print(f"{seconds:7.2f} s  {name:<32} {qualname}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
