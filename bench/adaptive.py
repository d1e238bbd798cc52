"""Adaptive sampling against uniform sampling on the chart suite: time to equal error.

    .venv/bin/python -m bench.adaptive [--scenes translucent_sphere backlit_slab ...] [--out CSV]

The scenes, their references (Mitsuba 3 volpath, 16384 spp, cached) and the error measure are
bench.accuracy's: every suite scene at 64×48 with its translucent material ``volumetric``, and the
frame's relative MSE mean((x − ref)²/(ref² + 0.01)) (the quantity ``render.target_error`` bounds
per pixel). Each scene is rendered uniformly at 16, 64, 256 and 1024 spp and adaptively at several
``render.target_error`` values (spp cap 1024), seed 7, wall time best of 2 after a warm-up. The
uniform time at the adaptive run's error is interpolated on the uniform log–log curve (slope −1
beyond its ends, the Monte Carlo rate); "saved" is 1 − t_adaptive / t_uniform at equal error
(negative: adaptive was slower). Also prints the frame mean over the reference's (the stopping
rule's bias shows there) and writes every row to ``--out`` (a CSV) when given.
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import numpy as np

from bench.accuracy import _loglog, reference, rel_mse, suite, with_method

UNIFORM_SPP = (16, 64, 256, 1024)
TARGETS = (0.05, 0.01, 0.002)
CAP = 1024


def run(data: dict) -> tuple[float, np.ndarray, float]:
    """(best wall time of 2, image, mean spp) of a scene dict."""
    from renderer.render import render_buffer
    from renderer.scene import load_scene
    from renderer.scene.compile import compile_scene

    cs = compile_scene(load_scene(data))
    best = np.inf
    for _ in range(2):
        t = time.perf_counter()
        buf = render_buffer(cs)
        best = min(best, time.perf_counter() - t)
    return best, buf.mean().astype(np.float64), float(buf.count.mean())


def main(argv: list[str] | None = None) -> int:
    scenes = suite()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=list(scenes), choices=list(scenes))
    parser.add_argument("--out", type=Path, default=None, help="write the rows to this CSV")
    args = parser.parse_args(argv)
    from renderer.render import render_buffer

    rows = []
    print(f"{'scene':<20} {'mode':<14} {'mean spp':>8} {'seconds':>8} {'relMSE':>9} "
          f"{'uniform s':>9} {'saved':>7} {'mean/ref':>9}")
    for name in args.scenes:
        scene, material = scenes[name]
        ref, _ = reference(name, scene, material, 16384)
        base = with_method(scene, material, "volumetric", 1)
        render_buffer(base)  # warm the JIT

        uniform = []
        for spp in UNIFORM_SPP:
            t, img, mean_spp = run(with_method(scene, material, "volumetric", spp))
            e = rel_mse(img, ref)
            uniform.append((t, e))
            rows.append({"scene": name, "mode": "uniform", "target": "", "mean_spp": mean_spp,
                         "seconds": t, "rel_mse": e, "uniform_seconds": t, "saved": 0.0,
                         "mean_over_ref": float(img.mean() / ref.mean())})
            print(f"{name:<20} {'uniform':<14} {mean_spp:>8.0f} {t:>8.3f} {e:>9.5f} "
                  f"{'':>9} {'':>7} {img.mean() / ref.mean():>9.4f}")
        ut = np.array([u[0] for u in uniform])
        ue = np.array([u[1] for u in uniform])
        for target in TARGETS:
            data = with_method(scene, material, "volumetric", CAP)
            data["render"]["target_error"] = target
            t, img, mean_spp = run(data)
            e = rel_mse(img, ref)
            # Uniform time at this error: invert the log–log curve (error falls as 1/time)
            t_uniform = _time_at_error(e, ut, ue)
            saved = 1 - t / t_uniform
            rows.append({"scene": name, "mode": "adaptive", "target": target,
                         "mean_spp": mean_spp, "seconds": t, "rel_mse": e,
                         "uniform_seconds": t_uniform, "saved": saved,
                         "mean_over_ref": float(img.mean() / ref.mean())})
            print(f"{name:<20} {'target ' + str(target):<14} {mean_spp:>8.0f} {t:>8.3f} "
                  f"{e:>9.5f} {t_uniform:>9.3f} {saved:>7.0%} {img.mean() / ref.mean():>9.4f}")
    if args.out is not None:
        with open(args.out, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    return 0


def _time_at_error(e: float, ut: np.ndarray, ue: np.ndarray) -> float:
    """The time a uniform curve (times ``ut``, errors ``ue``) takes to reach error ``e``: the
    error-against-time curve read the other way (its mirror ``_loglog(e, ue, ut)`` has the same
    slope −1 beyond the ends, since error ∝ 1/time there)."""
    return _loglog(e, ue, ut)


if __name__ == "__main__":
    raise SystemExit(main())
