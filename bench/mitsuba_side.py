"""Mitsuba 3's side of the speed comparison: how fast the reference renderer draws a Lucent scene.

Run from the repository root::

    .venv/bin/python -m bench.mitsuba_side

It times ``examples/cornell_box.json`` at its own resolution with 64 spp in the ``scalar_rgb`` and
``llvm_ad_rgb`` variants and prints a table. :func:`time_mitsuba` is the reusable part.

What is timed: the scene is loaded and rendered once first (``warmup_seconds``: scene build plus,
for the JIT variants, tracing and compiling the kernels; Dr.Jit caches kernels on disk, so a later
process may warm up faster). Then ``repeats`` renders of the loaded scene, each fully evaluated to a
NumPy array, with different seeds; ``seconds`` is the best of them. ``paths_per_second`` counts
camera paths, width·height·spp per render.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def time_mitsuba(scene: dict, spp: int, variant: str | None = None, repeats: int = 3) -> dict:
    """Time Mitsuba 3 rendering ``scene`` at ``spp``.

    Returns ``{"variant", "seconds", "warmup_seconds", "paths_per_second", "width", "height",
    "spp", "repeats"}``; ``seconds`` is the best of ``repeats`` renders after the warm-up render.
    """
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    from renderer.mitsuba_bridge import _use_variant, default_variant, to_mitsuba_dict

    if repeats < 1:
        raise ValueError("repeats: must be >= 1")
    mi = _use_variant(variant or default_variant())
    width, height = int(scene["film"]["width"]), int(scene["film"]["height"])

    # Warm-up: scene build, kernel tracing and compilation (JIT variants).
    start = time.perf_counter()
    mi_scene = mi.load_dict(to_mitsuba_dict(scene, variant=mi.variant()))
    np.array(mi.render(mi_scene, spp=spp, seed=0))
    warmup = time.perf_counter() - start

    best = float("inf")
    for k in range(repeats):
        start = time.perf_counter()
        np.array(mi.render(mi_scene, spp=spp, seed=k + 1))  # np.array forces evaluation
        best = min(best, time.perf_counter() - start)

    return {
        "variant": mi.variant(),
        "seconds": best,
        "warmup_seconds": warmup,
        "paths_per_second": width * height * spp / best,
        "width": width,
        "height": height,
        "spp": spp,
        "repeats": repeats,
    }


def main() -> int:
    scene = json.loads((ROOT / "examples" / "cornell_box.json").read_text())
    spp = 64
    print(
        f"cornell_box {scene['film']['width']}x{scene['film']['height']}, {spp} spp, "
        f"{os.cpu_count()} CPU cores"
    )
    print(f"{'variant':<12} {'seconds':>9} {'warm-up s':>10} {'Mpaths/s':>9}")
    for variant in ("scalar_rgb", "llvm_ad_rgb"):
        r = time_mitsuba(scene, spp, variant=variant)
        print(
            f"{r['variant']:<12} {r['seconds']:>9.3f} {r['warmup_seconds']:>10.3f} "
            f"{r['paths_per_second'] / 1e6:>9.3f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
