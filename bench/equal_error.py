"""Time to equal error: Lucent and Mitsuba 3, measured side by side in one run.

    .venv/bin/python -m bench.equal_error [--scenes cornell_box translucent_sphere backlit_slab]
                                          [--ladder 4 16 64 256 1024] [--target-spp 256]
    .venv/bin/python -m bench.equal_error --scenes env_diffuse_sphere env_rough_glass_sphere \
                                          env_wax_sphere   # lit by an environment image

Each scene is drawn at the resolution of its converged reference in ``tests/data/<name>_ref.npy``
(Mitsuba 3, 16384 spp, 64×48) by every renderer at a ladder of spp; each rung is timed (warm: the
kernels are loaded and the scene compiled by an untimed 1-spp render first) and its error measured
as the relative MSE against the reference, mean((I − ref)² / (ref² + 0.01)) over pixels and
channels. The target error is Mitsuba's own at ``--target-spp``; the time each renderer needs to
reach it is read off its ladder by log–log interpolation between the two rungs around it (or
extrapolated from the first rung as error ∝ 1/time when even that one is below the target). A
renderer whose error stops falling above the target (a biased method's floor) never reaches it and
is reported so, with its floor.

Renderers: Mitsuba 3 ``llvm_ad_rgb`` (``path`` / ``volpath`` through ``renderer.mitsuba_bridge``)
with its default ``independent`` sampler (the target's) and with ``ldsampler`` (its (0,2)-sequence
sampler), Lucent as the example is written (the ``volumetric`` method for the translucent scenes),
Lucent with ``render.sampler: sobol``, Lucent's packet kernel with each sampler where it covers
the scene (``renderer.packet``: the Cornell box), and Lucent with every translucent material
switched to ``method: auto`` (what the farm does when the user does not choose). Both renderers
use all cores. Mitsuba is an optional extra: without it the target is Lucent's own error at
``--target-spp``. Record results in docs/performance.md.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import platform
import time
from pathlib import Path

import numpy as np

from bench.accuracy import rel_mse

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"


def scene_at_reference(name: str, ref: np.ndarray, method: str | None = None,
                       sampler: str | None = None) -> dict:
    """The example at the reference's resolution; ``method`` replaces every translucent method,
    ``sampler`` sets ``render.sampler``. A scene kept beside its reference in tests/data/ (the
    environment-lit ``env_*``) is taken from there, its environment image's path made absolute."""
    data_scene = DATA / f"{name}.json"
    folder = DATA if data_scene.exists() else ROOT / "examples"
    scene = json.loads((folder / f"{name}.json").read_text())
    env = scene.get("environment")
    if env is not None and isinstance(env.get("image"), str):
        env["image"] = str((folder / env["image"]).resolve())
    scene["film"] = {"width": ref.shape[1], "height": ref.shape[0]}
    if sampler is not None:
        scene["render"]["sampler"] = sampler
    if method is not None:
        for material in scene["materials"].values():
            if material["type"] == "translucent":
                material["method"] = method
    return scene


def packet_covers(scene: dict) -> bool:
    """Whether Lucent's packet kernel renders this scene (``renderer.packet.unsupported``)."""
    from renderer.packet import unsupported
    from renderer.scene import load_scene
    from renderer.scene.compile import compile_scene

    return unsupported(compile_scene(load_scene(copy.deepcopy(scene), allow_paths=True))) is None


def ladder_lucent(scene: dict, ladder: list[int],
                  kernel: str = "scalar") -> list[tuple[int, float, np.ndarray]]:
    """(spp, seconds, image) for each rung; rung k uses seed k + 1 (independent images)."""
    from renderer.render import render
    from renderer.scene import load_scene
    from renderer.scene.compile import compile_scene

    compiled = compile_scene(load_scene(copy.deepcopy(scene), allow_paths=True))
    render(compiled, 1, kernel=kernel)  # loads the kernels (numba cache) outside the timing
    rungs = []
    for k, spp in enumerate(ladder):
        compiled.seed = k + 1
        start = time.perf_counter()
        image = render(compiled, spp, kernel=kernel)
        rungs.append((spp, time.perf_counter() - start, image))
    return rungs


def ladder_mitsuba(scene: dict, ladder: list[int], variant: str) -> list[tuple]:
    """As ``ladder_lucent`` for Mitsuba 3; the scene is loaded and its kernels traced first."""
    from renderer.mitsuba_bridge import _MAX_LANES_PER_PASS, _use_variant, to_mitsuba_dict

    mi = _use_variant(variant)
    mi_scene = mi.load_dict(to_mitsuba_dict(scene, variant=mi.variant()))
    pixels = scene["film"]["width"] * scene["film"]["height"]
    rungs = []
    for k, spp in enumerate([1, *ladder]):
        # As render_mitsuba: a JIT variant renders at most _MAX_LANES_PER_PASS samples at once
        n_passes = max(1, math.ceil(spp * pixels / _MAX_LANES_PER_PASS))
        start = time.perf_counter()
        total = 0.0
        for j in range(n_passes):
            pass_spp = spp // n_passes + (j < spp % n_passes)
            img = np.array(mi.render(mi_scene, spp=pass_spp, seed=1000 * k + j + 1))
            total = total + img.astype(np.float64) * pass_spp
        seconds = time.perf_counter() - start
        if k > 0:  # rung 0 (1 spp) traces and compiles the kernels: the warm-up
            rungs.append((spp, seconds, total / spp))
    return rungs


def time_to_error(points: list[tuple[float, float]], target: float) -> float | None:
    """Seconds to reach ``target`` on a ladder of (seconds, error), or None if it never does."""
    t0, e0 = points[0]
    if e0 <= target:
        return t0 * e0 / target  # error ∝ 1/time for an unbiased estimator
    for (ta, ea), (tb, eb) in zip(points, points[1:], strict=False):
        if eb <= target:
            if not ea > eb:
                return tb
            f = math.log(ea / target) / math.log(ea / eb)
            return math.exp(math.log(ta) + f * (math.log(tb) - math.log(ta)))
    return None


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", nargs="+",
                        default=["cornell_box", "translucent_sphere", "backlit_slab"])
    parser.add_argument("--ladder", nargs="+", type=int, default=[4, 16, 64, 256, 1024])
    parser.add_argument("--target-spp", type=int, default=256)
    parser.add_argument("--variant", default="llvm_ad_rgb")
    args = parser.parse_args()
    if args.target_spp not in args.ladder:
        parser.error("--target-spp must be one of the ladder's rungs")
    print(f"ladder {args.ladder} spp; {os.cpu_count()} cores, "
          f"{platform.processor() or platform.machine()}")
    print(f"{'scene':<20} {'renderer':<24} {'relMSE @ target spp':>20} {'s @ target spp':>15} "
          f"{'s to target':>26} {'Mitsuba ÷ it':>13}")
    for name in args.scenes:
        ref = np.load(DATA / f"{name}_ref.npy").astype(np.float64)
        runs = {}
        try:
            runs[f"mitsuba {args.variant}"] = ladder_mitsuba(
                scene_at_reference(name, ref), args.ladder, args.variant)
            runs[f"mitsuba {args.variant} ld"] = ladder_mitsuba(
                scene_at_reference(name, ref, sampler="sobol"), args.ladder, args.variant)
        except ImportError as err:
            print(f"mitsuba not installed ({err}); pip install 'lucent-farm[mitsuba]'")
        base = scene_at_reference(name, ref)
        runs["lucent"] = ladder_lucent(base, args.ladder)
        runs["lucent sobol"] = ladder_lucent(scene_at_reference(name, ref, sampler="sobol"),
                                             args.ladder)
        if packet_covers(base):
            runs["lucent packet"] = ladder_lucent(base, args.ladder, "packet")
            runs["lucent packet sobol"] = ladder_lucent(
                scene_at_reference(name, ref, sampler="sobol"), args.ladder, "packet")
        if any(m["type"] == "translucent" for m in base["materials"].values()):
            runs["lucent auto"] = ladder_lucent(scene_at_reference(name, ref, "auto"),
                                                args.ladder)
        at = args.ladder.index(args.target_spp)
        first = next(iter(runs.values()))
        target = rel_mse(first[at][2].astype(np.float64), ref)
        reach = {}
        for label, rungs in runs.items():
            points = [(seconds, rel_mse(img.astype(np.float64), ref)) for _, seconds, img in rungs]
            reach[label] = (points, time_to_error(points, target))
        base_time = next(iter(reach.values()))[1]
        for label, (points, seconds) in reach.items():
            if seconds is None:
                floor = min(e for _, e in points)
                shown, ratio = f"not in ladder (min {floor:.2g})", "—"
            else:
                shown, ratio = f"{seconds:.3f}", f"{base_time / seconds:.2f}"
            print(f"{name:<20} {label:<24} {points[at][1]:>20.3e} {points[at][0]:>15.3f} "
                  f"{shown:>26} {ratio:>13}")
        print(f"{name:<20} target relMSE {target:.3e} ({next(iter(runs))} at {args.target_spp} "
              "spp); relMSE per rung: " + "; ".join(
                  f"{label} " + " ".join(f"{e:.2e}" for _, e in reach[label][0])
                  for label in reach))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
