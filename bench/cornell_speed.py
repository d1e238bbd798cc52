"""Paths per second on the Cornell box: Lucent and Mitsuba 3, measured in the same run.

    .venv/bin/python -m bench.cornell_speed [--spp 64] [--repeats 3] [--scene examples/X.json]
        [--kernels scalar wavefront packet] [--variants scalar_rgb llvm_ad_rgb]

Both renderers draw the same scene (``examples/cornell_box.json`` unless ``--scene``) at the same
resolution, spp and depth (Lucent max_depth -1 ↔ Mitsuba -1; both use Russian roulette from 5
events on) on all cores. Lucent's time is the best of ``repeats`` renders after a warm-up render
(which includes loading its kernels from the numba cache, or compiling them on a cold cache; that
time is printed separately, as is Mitsuba's JIT warm-up). Mitsuba is an optional extra: without it
only Lucent's figures are printed. Lucent runs once with each of ``--kernels`` (``render_tile``'s
``kernel``: the one-path-at-a-time kernel, the wavefront kernel, the packet kernel of 16 paths
in the vector lanes), Mitsuba with each of
``--variants``; "lucent ÷ it" is the first kernel's paths/s over each row's. Record results in
docs/performance.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def time_lucent(scene: dict, spp: int, repeats: int = 3, kernel: str = "scalar") -> dict:
    from renderer.render import render_buffer
    from renderer.scene import load_scene
    from renderer.scene.compile import compile_scene

    start = time.perf_counter()
    compiled = compile_scene(load_scene(scene))
    render_buffer(compiled, 1, kernel=kernel)
    warmup = time.perf_counter() - start
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        render_buffer(compiled, spp, kernel=kernel)
        best = min(best, time.perf_counter() - start)
    paths = compiled.width * compiled.height * spp
    return {"seconds": best, "warmup_seconds": warmup, "paths_per_second": paths / best}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default=str(ROOT / "examples" / "cornell_box.json"))
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--kernels", nargs="+", choices=["scalar", "wavefront", "packet"],
                        default=["scalar", "wavefront"])
    parser.add_argument("--variants", nargs="*", default=["scalar_rgb", "llvm_ad_rgb"],
                        help="Mitsuba 3 variants to time (none: Lucent only)")
    args = parser.parse_args()
    scene = json.loads(Path(args.scene).read_text())
    w, h = scene["film"]["width"], scene["film"]["height"]
    print(f"{Path(args.scene).name}: {w}x{h}, {args.spp} spp, max_depth "
          f"{scene.get('render', {}).get('max_depth', -1)}; {os.cpu_count()} cores, "
          f"{platform.processor() or platform.machine()}")
    rows = [(f"lucent {kernel}", time_lucent(scene, args.spp, args.repeats, kernel))
            for kernel in args.kernels]
    try:
        from bench.mitsuba_side import time_mitsuba

        for variant in args.variants:
            try:
                rows.append((f"mitsuba {variant}",
                             time_mitsuba(scene, args.spp, variant, args.repeats)))
            except Exception as err:  # a variant may be unavailable (no libLLVM)
                print(f"mitsuba {variant}: unavailable ({err})")
    except ImportError as err:
        print(f"mitsuba not installed ({err}); pip install 'lucent-farm[mitsuba]'")
    lucent = rows[0][1]["paths_per_second"]
    print(f"{'renderer':<22} {'seconds':>8} {'warm-up s':>10} {'Mpaths/s':>9} {'lucent ÷ it':>12}")
    for name, r in rows:
        print(f"{name:<22} {r['seconds']:>8.3f} {r['warmup_seconds']:>10.2f} "
              f"{r['paths_per_second'] / 1e6:>9.2f} {lucent / r['paths_per_second']:>12.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
