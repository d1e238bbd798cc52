"""renderer/numba_inline.py: numba's inline="always" without the deep copies of a fresh callee.

The replacement must change how long a compile takes and nothing else: the same LLVM IR for
functions that inline nested device functions (closures, tuple returns, a callee at two sites, and
the tracer's own ray queries), compiled in fresh processes with it and without it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

from numba.core import inline_closurecall

from renderer import numba_inline

ROOT = Path(__file__).resolve().parents[2]

PROBE = textwrap.dedent('''
    import hashlib, json
    import numpy as np
    from numba import njit
    import renderer.numba_inline as ni
    from renderer.geometry.bvh import intersect_closest, occluded, traversal_stack
    from renderer.geometry.flat import flat_geometry

    @njit(inline="always")
    def leaf(a, b):
        s = 0.0
        for k in range(3):
            s += a[k] * b[k] if a[k] > 0 else -b[k]
        return s, (a[0], b[1])

    def make(c):
        @njit(inline="always")
        def closure(x):
            return x * c + leaf((x, 1.0, 2.0), (3.0, x, 4.0))[0]
        return closure

    closure = make(2.5)

    @njit(inline="always")
    def mid(x, y):
        u, w = leaf((x, y, 1.0), (y, x, 2.0))
        if u > 1.0:
            return closure(u) + w[0]
        return closure(y) - w[1]

    @njit
    def top(x):
        return mid(x, 2.0) + mid(2.0, x) + leaf((x, x, x), (1.0, 2.0, 3.0))[0]

    @njit(error_model="numpy")  # as the renderer's kernels: the inlined loop divides by 0
    def query(lo, hi, child, count, flat, kind, geo, o, d, stack):
        t, prim, u, v = intersect_closest(lo, hi, child, count, flat, kind, geo, o, d, np.inf,
                                          stack)
        return t + u + v + prim + occluded(lo, hi, child, count, flat, kind, geo, o, d, 1.0,
                                           stack)

    kind = np.array([1, 1], np.int8)
    geo = np.array([[-1.0, -1.0, 1.0, 2.0, 0, 0, 0, 2.0, 0],
                    [-1.0, -1.0, 2.0, 2.0, 0, 0, 0, 2.0, 0]])
    no_tree, no_nodes = np.zeros((0, 3, 8)), np.zeros((0, 8), np.int32)
    values = [top(0.7), top(-3.0),
              query(no_tree, no_tree, no_nodes, no_nodes, flat_geometry(kind, geo), kind, geo,
                    (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), traversal_stack(64))]
    ir = {f.__name__: hashlib.sha1(next(iter(f.inspect_llvm().values())).encode()).hexdigest()
          for f in (top, query)}
    print(json.dumps({"installed": ni.INSTALLED, "values": values, "ir": ir}))
''')


def probe(fast: str, cache: Path) -> dict:
    # An empty cache of its own (a kernel loaded from a cache is linked differently from one
    # just compiled, which shows in its caller's IR), one hash seed (numba iterates sets while
    # it names things)
    env = {**os.environ, "LUCENT_NUMBA_FAST_INLINE": fast, "LUCENT_CACHE_DIR": str(cache),
           "PYTHONHASHSEED": "0", "PYTHONPATH": str(ROOT)}
    env.pop("NUMBA_CACHE_DIR", None)  # set by `import renderer` in this process
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, check=True, capture_output=True,
                         text=True, timeout=300).stdout
    return json.loads(out.strip().splitlines()[-1])


def test_the_renderer_compiles_with_the_copy_free_inliner():
    # renderer.jit installs it before any kernel compiles; this numba has the known shape
    assert numba_inline.INSTALLED
    assert inline_closurecall.InlineWorker.inline_function is numba_inline.inline_function
    assert inline_closurecall.copy is numba_inline.copy  # swapped back after each inlining


def test_same_machine_code_with_and_without_it(tmp_path):
    fast, slow = probe("1", tmp_path / "fast"), probe("0", tmp_path / "slow")
    assert fast["installed"] and not slow["installed"]
    assert fast["values"] == slow["values"], (fast, slow)
    assert fast["values"][2] == 2.0  # the ray hits the nearer quad at t = 1, and is occluded
    assert fast["ir"] == slow["ir"], (fast, slow)
