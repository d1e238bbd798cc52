"""Denoising as a point on the speed–accuracy chart: Open Image Denoise on N spp against
undenoised uniform sampling at the same time.

    .venv/bin/python -m bench.denoise [--scenes ...] [--spp 4 16 64 256] [--repeat 2]

Scenes at 64×48 with converged Mitsuba 3 references (``bench.target_error.scenes``: the chart
suite's wax sphere and backlit slab, ``volumetric``, references in tests/data; the glass sphere,
a caustic). Each is rendered uniformly at 4 … 1024 spp (wall time of ``render_buffer``, best of
``--repeat`` after a warm-up) and, for each N of ``--spp``, rendered at N spp, its albedo and
normal AOVs traced (8 rays a pixel) and denoised (``renderer.film.denoise``, OIDN RT, HDR); its
time is the three together. "uniform at equal time" is the uniform relMSE at that time,
interpolated on the uniform log–log curve (slope −1 beyond its ends), and "spp" the samples a
pixel uniform sampling affords in it. The error is the chart suite's relMSE,
mean((x − ref)²/(ref² + 0.01)), over the frame, and over the "edge" pixels: the tenth of the
frame where the reference's luminance changes fastest (what a denoiser blurs).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bench.accuracy import _loglog, rel_mse
from bench.target_error import scene_at, scene_reference, scenes

UNIFORM_SPP = (4, 16, 64, 256, 1024)
DENOISED_SPP = (4, 16, 64, 256)
DEFAULT = ("translucent_sphere", "backlit_slab", "glass_sphere")
AOV_SPP = 8  # as `lucent render --denoise`


def edge_mask(ref: np.ndarray, share: float = 0.1) -> np.ndarray:
    """The ``share`` of pixels where the reference's luminance gradient is largest."""
    lum = ref @ np.array([0.2126, 0.7152, 0.0722])
    gy, gx = np.gradient(lum)
    g = np.hypot(gx, gy)
    return g >= np.quantile(g, 1.0 - share)


def spp_at(t: float, ts: np.ndarray, spp: np.ndarray) -> float:
    """Uniform samples a pixel affordable in time t (log–log linear; ∝ t beyond the ends)."""
    lt, ls = np.log(ts), np.log(spp)
    x = np.log(t)
    if x < lt[0] or x > lt[-1]:
        end = 0 if x < lt[0] else -1
        return float(spp[end] * t / ts[end])
    return float(np.exp(np.interp(x, lt, ls)))


def run(data: dict, repeat: int, denoised: bool) -> tuple[float, np.ndarray]:
    """(best wall time, image) of a render, denoised or not."""
    from renderer.film.aov import render_aovs
    from renderer.film.denoise import denoise
    from renderer.render import render_buffer
    from renderer.scene import load_scene
    from renderer.scene.compile import compile_scene

    cs = compile_scene(load_scene(data))
    best, img = np.inf, None
    for _ in range(repeat):
        t = time.perf_counter()
        img = render_buffer(cs).mean()
        if denoised:
            aov = render_aovs(cs, ["albedo", "normal"], spp=AOV_SPP)
            img = denoise(img, aov["albedo"], aov["normal"])
        best = min(best, time.perf_counter() - t)
    return best, np.asarray(img, np.float64)


def main(argv: list[str] | None = None) -> int:
    all_scenes = scenes()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=list(DEFAULT), choices=list(all_scenes))
    parser.add_argument("--spp", nargs="+", type=int, default=list(DENOISED_SPP))
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args(argv)
    from renderer.film.denoise import MISSING, oidn_available

    if not oidn_available():
        print(MISSING)
        return 2
    print(f"{'scene':<20} {'N spp':>5} {'seconds':>7} {'relMSE':>8} {'edges':>8} | "
          f"{'uniform at equal time: spp':>26} {'relMSE':>8} {'edges':>8}", flush=True)
    for name in args.scenes:
        scene, material = all_scenes[name]
        ref = scene_reference(name, scene, material)
        edges = edge_mask(ref)
        run(scene_at(scene, material, 1, None), 1, True)  # warm the JIT and OIDN
        ut, ue, ux = [], [], []
        for spp in UNIFORM_SPP:
            t, img = run(scene_at(scene, material, spp, None), args.repeat, False)
            ut.append(t)
            ue.append(rel_mse(img, ref))
            ux.append(rel_mse(img, ref, edges))
        ts, sp = np.array(ut), np.array(UNIFORM_SPP, float)
        for spp in args.spp:
            t, img = run(scene_at(scene, material, spp, None), args.repeat, True)
            e, x = rel_mse(img, ref), rel_mse(img, ref, edges)
            m = spp_at(t, ts, sp)
            print(f"{name:<20} {spp:>5} {t:>7.3f} {e:>8.5f} {x:>8.5f} | {m:>26.0f} "
                  f"{_loglog(t, ts, np.array(ue)):>8.5f} {_loglog(t, ts, np.array(ux)):>8.5f}",
                  flush=True)
        print(f"{name:<20} uniform: " + ", ".join(
            f"{s} spp {t:.3f} s {e:.5f}/{x:.5f}" for s, t, e, x in zip(UNIFORM_SPP, ut, ue, ux,
                                                                      strict=True)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
