"""``render.target_error`` against uniform sampling: achieved error / target, and time / uniform
time at the same error, per scene and target.

    .venv/bin/python -m bench.target_error [--scenes ...] [--targets 0.1 0.03 ...] [--seeds K]
                                           [--even] [--ref-spp N] [--out CSV] [--chart PNG]
    .venv/bin/python -m bench.target_error --overhead [--scenes ...] [--runs N]
    .venv/bin/python -m bench.target_error --radius [--scenes ...]
    .venv/bin/python -m bench.target_error --paired [--scenes ...] [--targets ...] [--pairs N]
    .venv/bin/python -m bench.target_error --spread [--scenes ...] [--targets ...] [--seeds K]
    .venv/bin/python -m bench.target_error --farm [--scenes ...] [--targets ...] [--seeds K]
    .venv/bin/python -m bench.target_error --farm-frames --scenes A B [--targets ...] [--seeds K]

The scenes: the chart suite (``bench.accuracy.suite``: wax sphere, backlit slab, concave torus,
thin shell, spheres at albedo 0.5/0.9/0.99, 64×48, the translucent material ``volumetric``,
Mitsuba 3 volpath references at 16384 spp, ``--ref-spp`` to change it), plus four scenes
outside it: the wax sphere in the Cornell box at 160×120 (its Mitsuba reference rendered once
and cached), and three with
committed Mitsuba references at 64×48: the glass sphere in the Cornell box (its caustic mostly
hidden under the sphere), the caustic floor (a glass sphere over an open floor under a small
light: the caustic in the sphere's shadow, and the light seen through the sphere from everywhere
on the floor as rare bright paths; very uneven noise) and the diffuse Cornell box (even noise).
The error is the chart suite's frame relMSE, mean((x − ref)²/(ref² + 0.01)), the quantity
``render.target_error`` is defined as (renderer/film/adaptive.py).

Each scene is rendered uniformly at 4, 8, 16, 64 … 4096 spp and with each target (``render.spp``
8192, which no target here reaches); wall time of the whole ``render_buffer`` call (the allocation's
bookkeeping included), best of ``--repeat`` after a warm-up (of more where that many took less
than a quarter second). With ``--seeds K`` every run is made with K seeds and its error and time
are the means over them (one seed's error is noisy where rare bright paths carry much of the
image). "uniform s" is the uniform time at the target run's achieved error, interpolated on the
uniform log–log curve (slope −1 beyond its ends; the
runs at 4 and 8 spp put a frame of a few milliseconds, where a target run takes the pilot's
first look of 4 spp, its 8 or a little more, between measured points: extrapolated down from
16 spp, time ∝ spp shrinks the fixed cost of a render too, and uniform sampling looked faster
than it is);
"time ratio" is the target run's time over it (below 1: the target run was faster at equal
error). "error/target" should lie in [0.5, 1.1]. ``--even`` runs each target a second time with
every round even, uniform sampling with the loop's pilot, rounds and stop (its frame is the
uniform render at its final count, sample for sample): "even ratio" is its time over uniform
sampling's at its error, the cost of the loop's structure alone, and "shape gain" the time
ratio over it, what the shape of the counts gains at equal error (below 1: it gains).
``--overhead`` times the loop's passes and its bookkeeping apart, against its samples rendered
in one pass (``overhead``); ``--radius`` what the shape of the counts gains from each window
radius of its estimates at a few samples a pixel (``radius_table``); ``--paired`` times each
target run and uniform sampling at its error in turns, so that the machine's drift between two
separate timings does not enter their ratio (``paired``); ``--spread`` runs each target with
many seeds (32 unless ``--seeds``), untimed, and gives the mean error/target (the expected
relMSE over the target, the quantity the target defines) with its standard error, and how far
single runs land from it: their median, 10th and 90th percentiles and the share in [0.5, 1.1]
(``spread``).
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import math
import time
from pathlib import Path

import numpy as np

from bench.accuracy import ROOT, _loglog, reference, rel_mse, suite, with_method

UNIFORM_SPP = (4, 8, 16, 64, 256, 1024, 4096)
TARGETS = (0.1, 0.03, 0.01, 0.003, 0.002)
CAP = 8192
# timed(): runs of a render are repeated until they have taken this long in all, at most so many
SHORT = 0.25
MOST_RUNS = 25
# outside the chart suite, references in tests/data
EXTRA = ("glass_sphere", "caustic_floor", "cornell_box")
# overhead(): each loop and its one-pass render timed as the best of so many runs
OVERHEAD_RUNS = 30


def scenes() -> dict[str, tuple[dict, str | None]]:
    out: dict[str, tuple[dict, str | None]] = dict(suite())
    # The scene: the wax sphere in the Cornell box at 160×120 (its reference rendered by
    # Mitsuba 3 and cached, as the suite's)
    wax = json.loads((ROOT / "examples" / "translucent_sphere.json").read_text())
    wax["film"] = {"width": 160, "height": 120}
    out["wax_cornell_160x120"] = (wax, "wax")
    for name in EXTRA:
        scene = json.loads((ROOT / "examples" / f"{name}.json").read_text())
        scene["film"] = {"width": 64, "height": 48}
        out[name] = (scene, None)
    return out


def scene_at(scene: dict, material: str | None, spp: int, target: float | None,
             seed: int = 7) -> dict:
    if material is not None:
        data = with_method(scene, material, "volumetric", spp)
    else:
        data = json.loads(json.dumps(scene))
        data["render"]["spp"] = spp
    data["render"].update(seed=seed, target_error=target)
    return data


# The suite's references' samples a pixel (--ref-spp): a frame of n samples measured against one
# of N has its relMSE raised by about n / N by the reference's own noise
REF_SPP = 16384


def scene_reference(name: str, scene: dict, material: str | None,
                    spp: int | None = None) -> np.ndarray:
    """The converged image of a scene of ``scenes()``: the suite's Mitsuba reference at ``spp``
    (``REF_SPP`` by default; cached), or the committed one in tests/data for the scenes outside
    the suite."""
    if material is not None:
        spp = spp or REF_SPP
        # (the committed references are of REF_SPP: another count is rendered, and cached)
        return reference(name, scene, material, spp, committed=spp == REF_SPP)[0]
    return np.load(ROOT / "tests" / "data" / f"{name}_ref.npy").astype(np.float64)


def measured(scene: dict, material: str | None, spp: int, target: float | None,
             ref: np.ndarray, seeds: int, repeat: int,
             even: bool = False) -> tuple[float, float, float]:
    """(wall time, relMSE, mean spp), each the mean over the seeds 7, 8, … (``seeds`` of them):
    one seed's error is noisy where rare bright paths carry much of the image. ``even``: the
    target loop with every round even (``render_buffer``'s ``even``)."""
    runs = [timed(scene_at(scene, material, spp, target, 7 + k), repeat, even)
            for k in range(seeds)]
    return (float(np.mean([t for t, _, _ in runs])),
            float(np.mean([rel_mse(img, ref) for _, img, _ in runs])),
            float(np.mean([n for _, _, n in runs])))


def timed(data: dict, repeat: int, even: bool = False) -> tuple[float, np.ndarray, float]:
    """(best wall time, image, mean spp): the best of ``repeat`` runs, and of more while they
    have taken less than ``SHORT`` seconds in all (at most ``MOST_RUNS``): a frame of
    milliseconds is otherwise at the mercy of one slow run (the diffuse Cornell box's 8-spp
    pilot, the same work in both, measured 1.29 and 1.03× uniform sampling's time in one run
    of the bench at ``--repeat 1``)."""
    from renderer.render import render_buffer
    from renderer.scene import load_scene
    from renderer.scene.compile import compile_scene

    cs = compile_scene(load_scene(data))
    best, spent, runs = np.inf, 0.0, 0
    while runs < repeat or (spent < SHORT and runs < MOST_RUNS):
        t = time.perf_counter()
        buf = render_buffer(cs, even=even)
        took = time.perf_counter() - t
        best, spent, runs = min(best, took), spent + took, runs + 1
    return best, buf.mean().astype(np.float64), float(buf.count.mean())


def main(argv: list[str] | None = None) -> int:
    all_scenes = scenes()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=None, choices=list(all_scenes),
                        help="default all; with --replay all but the wax sphere at 160×120 "
                             "(its replay holds about 10 GB)")
    parser.add_argument("--targets", nargs="+", type=float, default=None,
                        help=f"default {' '.join(map(str, TARGETS))}; with --replay "
                             f"{' '.join(map(str, REPLAY_TARGETS))}")
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--runs", type=int, default=None,
                        help=f"--overhead: the best of this many runs ({OVERHEAD_RUNS}); "
                             f"--replay: the loop's runs on a scene's stash ({REPLAY_RUNS})")
    parser.add_argument("--seeds", type=int, default=None,
                        help="average each run's error and time over this many seeds (7, 8, …; "
                             f"default 1, with --spread {SPREAD_SEEDS})")
    parser.add_argument("--out", type=Path, default=None, help="write the rows to this CSV")
    parser.add_argument("--chart", type=Path, default=None, help="draw the chart to this PNG")
    parser.add_argument("--oracle", action="store_true",
                        help="print the time ratio an allocation could reach at best instead")
    parser.add_argument("--farm", action="store_true",
                        help="the farm's rule instead: each scene and target as a job on an "
                             "embedded farm (2 worker processes, tiles of 16 px)")
    parser.add_argument("--farm-frames", action="store_true",
                        help="the scenes as the frames of one farm job a target and seed "
                             "(same film size): each frame's error / target")
    parser.add_argument("--radius", action="store_true",
                        help="print what the shape from each window radius gains, by samples "
                             "a pixel, against the true variance, instead")
    parser.add_argument("--overhead", action="store_true",
                        help="time the target loop's passes and its bookkeeping apart instead, "
                             "against its samples rendered in one pass")
    parser.add_argument("--replay", action="store_true",
                        help="run the loop on draws from a stash of each scene's samples "
                             "instead: its error and its cost counted, without timing noise")
    parser.add_argument("--ref-spp", type=int, default=REF_SPP,
                        help="the suite's Mitsuba references at this many samples a pixel "
                             "(other than 16384, the committed ones too are rendered, and "
                             "cached; a reference's own noise adds about spp / ref-spp to a "
                             "frame's measured relMSE)")
    parser.add_argument("--paired", action="store_true",
                        help="time each target run against uniform sampling at its error in "
                             "pairs, in turns, instead (--pairs of them, --seeds of each)")
    parser.add_argument("--pairs", type=int, default=PAIRS)
    parser.add_argument("--spread", action="store_true",
                        help="run each target with --seeds seeds, untimed, and print the mean "
                             "error/target and the spread of single runs instead")
    parser.add_argument("--even", action="store_true",
                        help="also run each target with every round even (uniform sampling "
                             "with the loop's rounds and stop) and print what the shape gains")
    args = parser.parse_args(argv)
    if args.replay:
        names = args.scenes or [n for n in all_scenes if n != "wax_cornell_160x120"]
        rows = replay(names, all_scenes, args.targets or list(REPLAY_TARGETS),
                      args.runs or REPLAY_RUNS)
        if args.out is not None:
            _write_csv(rows, args.out)
        return 0
    args.scenes = args.scenes or list(all_scenes)
    args.targets = args.targets or list(TARGETS)
    if args.oracle:
        return oracle(args.scenes, all_scenes)
    if args.farm:
        return farm(args.scenes, all_scenes, args.targets, args.seeds or 1)
    if args.farm_frames:
        return farm_frames(args.scenes, all_scenes, args.targets, args.seeds or 1)
    if args.spread:
        rows = spread(args.scenes, all_scenes, args.targets, args.seeds or SPREAD_SEEDS,
                      args.ref_spp)
        if args.out is not None:
            _write_csv(rows, args.out)
        return 0
    args.seeds = args.seeds or 1
    if args.paired:
        rows = paired(args.scenes, all_scenes, args.targets, args.pairs, args.seeds,
                      args.ref_spp)
        if args.out is not None:
            _write_csv(rows, args.out)
        return 0
    if args.radius:
        radius_table(args.scenes, all_scenes)
        return 0
    if args.overhead:
        overhead(args.scenes, all_scenes, args.targets, args.runs or OVERHEAD_RUNS)
        return 0
    from renderer.render import render_buffer

    rows = []
    print(f"{'scene':<20} {'target':>7} {'mean spp':>8} {'seconds':>8} {'relMSE':>9} "
          f"{'err/target':>10} {'uniform s':>9} {'time ratio':>10}"
          + (f" {'even spp':>8} {'even ratio':>10} {'shape gain':>10}" if args.even else ""),
          flush=True)
    for name in args.scenes:
        scene, material = all_scenes[name]
        ref = scene_reference(name, scene, material, args.ref_spp)
        # Warm the JIT: the render kernel, and the adaptive loop's kernels (a --repeat 1 run's
        # first target would otherwise load or compile them inside its time)
        render_buffer(scene_at(scene, material, 1, None))
        render_buffer(scene_at(scene, material, 24, 1e-4))
        ut, ue = [], []
        for spp in UNIFORM_SPP:
            t, e, _ = measured(scene, material, spp, None, ref, args.seeds, args.repeat)
            ut.append(t)
            ue.append(e)
            rows.append({"scene": name, "mode": "uniform", "target": "", "mean_spp": spp,
                         "seconds": t, "rel_mse": ue[-1], "ratio": "", "uniform_seconds": t,
                         "time_ratio": 1.0})
        for target in args.targets:
            t, e, mean_spp = measured(scene, material, CAP, target, ref, args.seeds,
                                      args.repeat)
            t_uniform = _loglog(e, np.array(ue), np.array(ut))
            rows.append({"scene": name, "mode": "target", "target": target,
                         "mean_spp": mean_spp, "seconds": t, "rel_mse": e, "ratio": e / target,
                         "uniform_seconds": t_uniform, "time_ratio": t / t_uniform})
            line = (f"{name:<20} {target:>7} {mean_spp:>8.0f} {t:>8.3f} {e:>9.5f} "
                    f"{e / target:>10.2f} {t_uniform:>9.3f} {t / t_uniform:>10.2f}")
            if args.even:
                # The same loop with every round even: its time over uniform sampling's is the
                # cost of the rounds and the stop alone; the rule's ratio over it, what the
                # shape of the counts gains at equal error
                te, ee, spp_even = measured(scene, material, CAP, target, ref, args.seeds,
                                            args.repeat, even=True)
                te_uniform = _loglog(ee, np.array(ue), np.array(ut))
                even_ratio = te / te_uniform
                rows.append({"scene": name, "mode": "even", "target": target,
                             "mean_spp": spp_even, "seconds": te, "rel_mse": ee,
                             "ratio": ee / target, "uniform_seconds": te_uniform,
                             "time_ratio": even_ratio})
                line += (f" {spp_even:>8.0f} {even_ratio:>10.2f} "
                         f"{t / t_uniform / even_ratio:>10.2f}")
            print(line, flush=True)
    target_rows = [r for r in rows if r["mode"] == "target"]
    ratios = np.array([r["ratio"] for r in target_rows])
    times = np.array([r["time_ratio"] for r in target_rows])
    print(f"error/target {ratios.min():.2f}–{ratios.max():.2f} "
          f"({np.mean((ratios >= 0.5) & (ratios <= 1.1)):.0%} in [0.5, 1.1]); "
          f"time/uniform {times.min():.2f}–{times.max():.2f} (median {np.median(times):.2f})")
    if args.even:
        even = np.array([r["time_ratio"] for r in rows if r["mode"] == "even"])
        gain = times / even
        print(f"even rounds' time/uniform {even.min():.2f}–{even.max():.2f} (median "
              f"{np.median(even):.2f}); shape gain {gain.min():.2f}–{gain.max():.2f} (median "
              f"{np.median(gain):.2f}, {np.sum(gain > 1)} of {gain.size} above 1)")
    if args.out is not None:
        _write_csv(rows, args.out)
    if args.chart is not None:
        chart(target_rows, args.chart)
    return 0


def _write_csv(rows: list[dict], path: Path) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def _box3(a: np.ndarray) -> np.ndarray:
    """The mean of each pixel's 3×3 window (itself included; the frame's edge counts fewer)."""
    h, w = a.shape
    pa, pk = np.pad(a, 1), np.pad(np.ones((h, w)), 1)
    total, count = np.zeros((h, w)), np.zeros((h, w))
    for dy in range(3):
        for dx in range(3):
            total += pa[dy:dy + h, dx:dx + w]
            count += pk[dy:dy + h, dx:dx + w]
    return total / count


def variance_and_cost(data: dict, ref: np.ndarray):
    """A uniform render of ``data``: (its buffer, each pixel's per-sample relative variance
    against the reference ``ref``, (h, w), and its cost a sample in path segments + 1)."""
    from renderer.render import render_buffer
    from renderer.scene import load_scene

    buf = render_buffer(load_scene(data))
    n = buf.count[..., None]
    mean = buf.sum / n
    s2 = (buf.sum_sq - n * mean * mean) / (n - 1)
    assert buf.segments is not None
    return buf, np.mean(s2 / (ref**2 + 0.01), axis=-1), buf.segments / buf.count + 1.0


def shape_price(v: np.ndarray, c: np.ndarray, shape: np.ndarray) -> float:
    """The time to a frame error with counts n_p ∝ shape_p over uniform sampling's, for per-sample
    variances ``v`` and costs ``c``: mean(c s)·mean(v / s) / (mean(c)·mean(v))."""
    return float((c * shape).mean() * (v / shape).mean() / (v.mean() * c.mean()))


def oracle(names: list[str], all_scenes: dict) -> int:
    """What per-pixel allocation can gain, from a uniform 1024-spp render, the reference, and a
    second, independent render at 4096 spp. For a shape s_p of the counts (n_p ∝ s_p) the time
    to a given frame error is ∝ mean(c s)·mean(v / s), against mean(c)·mean(v) for uniform
    sampling (v_p the 1024-spp render's relative variance against the reference, c_p its cost:
    path segments + 1 a sample); the columns are that ratio for

    - "same run": s = √(v/c) from the 1024-spp render itself (the ratio is then
      mean(√(vc))² / (mean(c)·mean(v)), never above 1 by Cauchy–Schwarz). Not reachable: it
      knows where this render's rare bright paths fell (its v is the realised variance, its
      own noise included), so it is optimistic;
    - "independent": s = √(v'/c') from the 4096-spp render, each averaged over 3×3: a shape
      fixed before the samples it weighs, as any allocation's is, from 4× the samples (roughly
      the best such a shape can do; unaveraged, the independent map's own noise made it worse);
    - "estimator": the shape the renderer can know, √(ṽ/c̃) from the 1024-spp render's
      neighbours (renderer.film.adaptive: 5×5 leave-one-out, floored).

    Two more columns price the estimator's shape in measured time instead of path segments
    (``timed_cost``: c_p is the pixel's segments a sample times its 8×8 tile's seconds a
    segment): "est., timed", the renderer's shape so priced; "timed shape", the shape made
    with that measured cost in place of c̃ (√(ṽ/(c̃ t)), t the tile's seconds a segment). Their
    difference is what an allocation that knew each pixel's time could gain over the path
    segments' count.

    The last column, "predicted @32", is what the rule's own estimates say the shape would gain
    when it decides a round's counts: ``predicted_gain`` of ṽ and c̃·t from a uniform 32-spp
    render (the loop's frame after the pilot and its even round), the range over the seeds 7–10.
    A rule that shaped only where its estimates predict a gain would need this column to follow
    "est., timed"."""
    from renderer.film.adaptive import shape_estimates
    from renderer.render import render_buffer
    from renderer.scene import load_scene

    ratio = shape_price
    print(f"{'scene':<22} {'same run':>9} {'independent':>12} {'estimator':>10} "
          f"{'est., timed':>12} {'timed shape':>12} {'predicted @32':>14}"
          "   (time / uniform time at equal error)")
    for name in names:
        scene, material = all_scenes[name]
        ref = scene_reference(name, scene, material)
        buf, v, c = variance_and_cost(scene_at(scene, material, 1024, None), ref)
        other = scene_at(scene, material, 4096, None)
        other["render"]["seed"] = 99991
        _, v2, c2 = variance_and_cost(other, ref)
        shape = np.sqrt(_box3(v2) / _box3(c2))
        shape = np.maximum(shape, 1e-12 * shape.max())  # no pixel left without samples
        same = np.sqrt(v * c).mean() ** 2 / (v.mean() * c.mean())
        nv, nc = shape_estimates(buf)
        assert nc is not None
        per_segment = timed_cost(scene_at(scene, material, 32, None))
        timed = (c - 1.0) * per_segment  # seconds a sample
        predicted = []
        for seed in (7, 8, 9, 10):
            early = render_buffer(load_scene(scene_at(scene, material, 32, None, seed)))
            ev, ec = shape_estimates(early)
            assert ec is not None
            predicted.append(predicted_gain(ev, (ec - 1.0) * per_segment))
        print(f"{name:<22} {same:>9.2f} {ratio(v, c, shape):>12.2f} "
              f"{ratio(v, c, np.sqrt(nv / nc)):>10.2f} "
              f"{ratio(v, timed, np.sqrt(nv / nc)):>12.2f} "
              f"{ratio(v, timed, np.sqrt(nv / (nc * per_segment))):>12.2f} "
              f"{f'{min(predicted):.2f}–{max(predicted):.2f}':>14}", flush=True)
    return 0


RADIUS_SPP = (16, 32, 64, 256)
RADII = (1, 2, 4, 6, 8, 12)


def radius_table(names: list[str], all_scenes: dict, spps: tuple[int, ...] = RADIUS_SPP,
                 radii: tuple[int, ...] = RADII, seeds: tuple[int, ...] = (7, 8)) -> list[dict]:
    """What the shape of the counts gains from the estimates of a window of each radius, at a few
    samples a pixel: for a uniform render at each of ``spps`` (seeds ``seeds``), the shape
    s = √(ṽ/c̃) of ``shape_estimates`` at each radius, priced as ``oracle`` prices a shape
    (the time to a frame error over uniform sampling's, mean(c s)·mean(v / s) / (mean(c)·mean(v)),
    v a uniform 1024-spp render's relative variance against the reference and c its path
    segments a sample times its tile's measured seconds a segment, ``timed_cost``), the mean
    over the seeds; below 1 the shape gains. The rule's window is 5×5, radius ``RADIUS`` = 2.
    Returns the rows it prints."""
    from renderer.film.adaptive import shape_estimates
    from renderer.render import render_buffer
    from renderer.scene import load_scene

    rows = []
    print(f"{'scene':<22} {'spp':>5} " + " ".join(f"{f'r={r}':>7}" for r in radii)
          + "   (time / uniform time at equal error)")
    for name in names:
        scene, material = all_scenes[name]
        ref = scene_reference(name, scene, material)
        _, v, segments = variance_and_cost(scene_at(scene, material, 1024, None), ref)
        per_segment = timed_cost(scene_at(scene, material, 32, None))
        c = (segments - 1.0) * per_segment
        for spp in spps:
            gains: dict[int, list[float]] = {r: [] for r in radii}
            for seed in seeds:
                early = render_buffer(load_scene(scene_at(scene, material, spp, None, seed)))
                for r in radii:
                    ev, ec = shape_estimates(early, radius=r)
                    assert ec is not None
                    shape = np.sqrt(ev / ((ec - 1.0) * per_segment))
                    gains[r].append(shape_price(v, c, shape))
            row = {"scene": name, "spp": spp,
                   **{f"r{r}": float(np.mean(gains[r])) for r in radii}}
            rows.append(row)
            print(f"{name:<22} {spp:>5} "
                  + " ".join(f"{row[f'r{r}']:>7.3f}" for r in radii), flush=True)
    return rows


def predicted_gain(v: np.ndarray, c: np.ndarray) -> float:
    """The time to a frame error with counts n ∝ √(v/c), over uniform sampling's, were v each
    pixel's true variance and c its cost a sample: mean(√(v c))² / (mean(v)·mean(c)), at most 1
    (Cauchy–Schwarz), 1 where v ∝ c (then the best counts are even)."""
    return float(np.sqrt(v * c).mean() ** 2 / (v.mean() * c.mean()))


def timed_cost(data: dict, tile: int = 8) -> np.ndarray:
    """Each pixel's seconds a path segment, measured: the frame rendered uniformly in tiles of
    ``tile`` px, one thread, each tile's wall time (best of two) over its path segments; (h, w),
    every pixel of a tile the tile's figure."""
    import numba

    from renderer.render import render_tile
    from renderer.scene import load_scene
    from renderer.scene.compile import compile_scene

    cs = compile_scene(load_scene(data))
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    out = np.zeros((cs.height, cs.width))
    try:
        render_tile(cs, 0, 0, 1, 1, 0, 1)  # the kernel loaded before any tile is timed
        for y in range(0, cs.height, tile):
            for x in range(0, cs.width, tile):
                w, h = min(tile, cs.width - x), min(tile, cs.height - y)
                best, segments = np.inf, 1
                for _ in range(2):
                    start = time.perf_counter()
                    buf = render_tile(cs, x, y, w, h, 0, cs.spp)
                    best = min(best, time.perf_counter() - start)
                    assert buf.segments is not None
                    segments = max(int(buf.segments.sum()), 1)
                out[y:y + h, x:x + w] = best / segments
    finally:
        numba.set_num_threads(threads)
    return out


def overhead(names: list[str], all_scenes: dict, targets: list[float],
             runs: int = OVERHEAD_RUNS) -> list[dict]:
    """What the target loop costs besides its samples (``--overhead``), per scene, target and
    mode (the rule, and its even variant): ``render_buffer`` timed whole, the best of ``runs``,
    and within that run the time spent in its passes (``render_tile`` calls); "book ms", the
    rest, is the loop's bookkeeping (the estimates, the allocation, the stop). "one pass ms" is
    the same counts (the loop's final count of every pixel) rendered in one pass, the best of
    ``runs``: "loop / one pass" is the loop's structure, its rounds and their bookkeeping, at
    equal samples (the rule's rounds leave gaps in a pixel's indices, so its one pass renders
    as many samples, not the same ones). Returns the rows it prints."""
    import renderer.render as render_module
    from renderer.scene import load_scene
    from renderer.scene.compile import compile_scene

    real = render_module.render_tile
    in_passes = [0.0, 0]

    def timed_tile(*args, **kwargs):
        start = time.perf_counter()
        try:
            return real(*args, **kwargs)
        finally:
            in_passes[0] += time.perf_counter() - start
            in_passes[1] += 1

    rows = []
    print(f"{'scene':<20} {'target':>7} {'mode':>5} {'passes':>6} {'mean spp':>8} "
          f"{'loop ms':>8} {'passes ms':>9} {'book ms':>8} {'one pass ms':>11} "
          f"{'loop / one pass':>15}", flush=True)
    for name in names:
        scene, material = all_scenes[name]
        for target in targets:
            cs = compile_scene(load_scene(scene_at(scene, material, CAP, target)))
            for mode in ("rule", "even"):
                # (the loop's final counts, and the kernels loaded)
                counts = render_module.render_buffer(cs, even=mode == "even").count
                counts = counts.astype(np.int32)
                best, one = (np.inf, 0.0, 0), np.inf
                for _ in range(runs):
                    # The loop and its one pass in turns, so that both see the machine alike
                    in_passes[:] = [0.0, 0]
                    render_module.render_tile = timed_tile
                    try:
                        start = time.perf_counter()
                        buf = render_module.render_buffer(cs, even=mode == "even")
                        took = time.perf_counter() - start
                    finally:
                        render_module.render_tile = real
                    if took < best[0]:
                        best = (took, in_passes[0], in_passes[1])
                    start = time.perf_counter()
                    real(cs, 0, 0, cs.width, cs.height, 0, int(counts.max()), counts)
                    one = min(one, time.perf_counter() - start)
                took, passes_s, passes = best
                row = {"scene": name, "target": target, "mode": mode, "passes": passes,
                       "mean_spp": float(buf.count.mean()), "loop_ms": 1e3 * took,
                       "passes_ms": 1e3 * passes_s, "book_ms": 1e3 * (took - passes_s),
                       "one_pass_ms": 1e3 * one, "structure": took / one}
                rows.append(row)
                print(f"{name:<20} {target:>7} {mode:>5} {passes:>6} {row['mean_spp']:>8.1f} "
                      f"{row['loop_ms']:>8.2f} {row['passes_ms']:>9.2f} {row['book_ms']:>8.2f} "
                      f"{row['one_pass_ms']:>11.2f} {row['structure']:>15.2f}", flush=True)
    return rows


# replay(): the stash's samples a pixel, the loop's draws from it (with replacement) a pixel, runs
REPLAY_SAMPLES = 2048
REPLAY_DRAWS = 3 * REPLAY_SAMPLES
REPLAY_RUNS = 16
REPLAY_TARGETS = (0.1, 0.03, 0.01)


def stash(data: dict, samples: int) -> tuple[np.ndarray, np.ndarray]:
    """Every sample of a uniform render of ``data``, one by one: (its radiance, (samples, h, w,
    3) float32, and its path segments, (samples, h, w) float32), sample k of each pixel being
    the one ``render_tile`` gives at index k."""
    from renderer.render import render_tile
    from renderer.scene import load_scene
    from renderer.scene.compile import compile_scene

    cs = compile_scene(load_scene(data))
    h, w = cs.height, cs.width
    radiance = np.zeros((samples, h, w, 3), np.float32)
    segments = np.zeros((samples, h, w), np.float32)
    for k in range(samples):
        buf = render_tile(cs, 0, 0, w, h, k, 1)
        assert buf.segments is not None
        radiance[k], segments[k] = buf.sum, buf.segments
    return radiance, segments


class StashReplay:
    """A ``render_pass`` for ``sample_to_target`` that renders nothing: each pixel's samples are
    drawn from the stash's samples of that pixel, uniformly and with replacement (the stash is
    then exactly the distribution sampled, its mean the converged image), ``draws`` of them a
    pixel at most, in an order fixed by ``rng``; a pass hands each pixel the next ``counts[p]``
    of its draws. The loop's decisions are the renderer's own (they see only the buffers)."""

    def __init__(self, radiance: np.ndarray, segments: np.ndarray, rng: np.random.Generator,
                 draws: int = REPLAY_DRAWS):
        samples, h, w, _ = radiance.shape
        pick = rng.integers(0, samples, size=(draws, h, w))

        def running(a: np.ndarray) -> np.ndarray:
            out = np.zeros((draws + 1,) + a.shape[1:])
            np.cumsum(a, axis=0, out=out[1:])
            return out

        drawn = np.take_along_axis(radiance, pick[..., None], axis=0).astype(np.float64)
        self._sum, self._sum_sq = running(drawn), running(drawn * drawn)
        del drawn
        self._segments = running(np.take_along_axis(segments, pick, axis=0))
        self.used = np.zeros((h, w), np.int64)
        self.draws = draws
        self._rows, self._cols = np.indices((h, w))

    def __call__(self, index: int, counts: np.ndarray):
        from renderer.film.buffer import SampleBuffer

        start, end = self.used, self.used + counts
        if (end > self.draws).any():
            raise ValueError(f"a pixel asked for more than the replay's {self.draws} draws")
        at = (self._rows, self._cols)
        buf = SampleBuffer.empty(0, 0, counts.shape[1], counts.shape[0])
        buf.sum[:] = self._sum[(end,) + at] - self._sum[(start,) + at]
        buf.sum_sq[:] = self._sum_sq[(end,) + at] - self._sum_sq[(start,) + at]
        buf.segments[:] = np.rint(self._segments[(end,) + at]
                                  - self._segments[(start,) + at]).astype(np.int64)
        buf.count[:] = counts
        self.used = end
        return buf


def stash_truth(radiance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the stash's mean, (h, w, 3), and each pixel's per-sample relative variance, (h, w)): the
    converged image and the variance of the distribution a replay samples (its population
    variance, over the squared mean plus 0.01, averaged over the channels)."""
    mean = radiance.mean(axis=0, dtype=np.float64)
    var = radiance.var(axis=0, dtype=np.float64)
    return mean, (var / (mean * mean + 0.01)).mean(axis=-1)


def replay(names: list[str], all_scenes: dict, targets: list[float] = REPLAY_TARGETS,
           runs: int = REPLAY_RUNS, samples: int = REPLAY_SAMPLES,
           draws: int = REPLAY_DRAWS) -> list[dict]:
    """The target loop without timing noise (``--replay``): per scene, a stash of ``samples``
    samples a pixel (``stash``, seed 7), and the loop (the rule, and its even variant) run
    ``runs`` times on draws from it (``StashReplay``, seeds 0, 1, …), each at every target.
    Its error is measured against the stash's mean (the replay's converged image), its cost
    counted, not timed: in path segments + 1 a sample (the cost the rule weighs), and in
    seconds (each pixel's segments times its 8×8 tile's measured seconds a segment,
    ``timed_cost``, measured once). Uniform sampling in the same world reaches an error e at
    n = mean(v) / e samples a pixel exactly (v the stash's per-sample relative variance: its
    draws are independent), so "segments ratio" and "time ratio" are the loop's mean cost over
    runs times its mean error, over mean(v) times uniform sampling's cost a sample a pixel:
    its cost over uniform sampling's at equal error; after "±", the spread of each run's own
    time ratio (its cost times its error) over √runs, a standard error: the loop's samples vary
    from run to run, and with them its counts and its stop. "shape gain" is the rule's time
    ratio over its even variant's. "priced/t" is the error its counts are priced at, mean(v / n)
    over the target (the mean over runs), as ``oracle`` and ``radius_table`` price a shape. The
    loop's error can be below it: its counts go together with the samples it drew (its rounds
    and its stop read them), where fresh draws at the same counts would reach the priced error
    (docs/adaptive-sampling.md).
    Returns the rows it prints."""
    from renderer.film.adaptive import sample_to_target

    rows = []
    print(f"{'scene':<20} {'target':>7} {'mode':>5} {'mean spp':>8} {'err/target':>10} "
          f"{'priced/t':>10} {'segments ratio':>14} {'time ratio':>15} {'shape gain':>10}",
          flush=True)
    for name in names:
        scene, material = all_scenes[name]
        radiance, segments = stash(scene_at(scene, material, samples, None), samples)
        mean, v = stash_truth(radiance)
        per_segment = timed_cost(scene_at(scene, material, 32, None))
        mean_segments = segments.mean(axis=0, dtype=np.float64)
        costs = {"segments": mean_segments + 1.0, "seconds": mean_segments * per_segment}
        runs_of: dict[tuple, list] = {}
        for run in range(runs):
            source = StashReplay(radiance, segments, np.random.default_rng(run), draws)
            for target in targets:
                for mode in ("rule", "even"):
                    source.used[:] = 0
                    buf = sample_to_target(source, v.shape, target, draws,
                                           even=mode == "even")
                    n = buf.count.astype(np.float64)
                    error = rel_mse(buf.sum / n[..., None], mean)
                    runs_of.setdefault((target, mode), []).append(
                        (error, float((v / n).mean()), n.mean(),
                         *(float((c * n).sum()) for c in costs.values())))
            del source
        for target in targets:
            ratios = {}
            for mode in ("rule", "even"):
                per_run = np.array(runs_of[(target, mode)])
                error, priced, spp, *spent = per_run.mean(axis=0)
                ratio = [cost * error / (v.mean() * c.sum())
                         for cost, c in zip(spent, costs.values(), strict=True)]
                # (the spread of each run's own time ratio, over √runs: its error times its
                # cost in seconds, the first and last of its figures)
                spread = float(np.std(per_run[:, 0] * per_run[:, -1])
                               / (v.mean() * costs["seconds"].sum() * np.sqrt(len(per_run))))
                ratios[mode] = ratio[1]
                row = {"scene": name, "target": target, "mode": mode, "mean_spp": spp,
                       "ratio": error / target, "priced_ratio": priced / target,
                       "segments_ratio": ratio[0],
                       "time_ratio": ratio[1], "time_ratio_se": spread,
                       "shape_gain": ratios["rule"] / ratio[1] if mode == "even" else ""}
                rows.append(row)
                gain = f"{row['shape_gain']:>10.3f}" if mode == "even" else ""
                print(f"{name:<20} {target:>7} {mode:>5} {spp:>8.0f} {row['ratio']:>10.2f} "
                      f"{row['priced_ratio']:>10.2f} {row['segments_ratio']:>14.3f} "
                      f"{row['time_ratio']:>7.3f} ± {spread:.3f} {gain}",
                      flush=True)
    return rows


# paired(): pairs of timings, the target run and uniform sampling at its error in turns
PAIRS = 7
# equal_error_spp(): fixed-point steps of n ← n e(n) / error
EQUAL_ERROR_STEPS = 4


def equal_error_spp(error_at, error: float, start: float,
                    steps: int = EQUAL_ERROR_STEPS) -> float:
    """The samples a pixel (not a whole number) at which uniform sampling's relMSE is ``error``,
    given ``error_at(n)``, its relMSE at n samples a pixel (n whole): uniform sampling's relMSE
    is c / n in expectation, so n = m · e(m) / error for any m; taken at m near the answer
    (from ``start``, then each step's answer rounded) the reading is of renders near the
    error asked, where a frame's own fluctuations and any floor of the error (the reference's
    noise) are what they are at it."""
    n = max(1.0, float(start))
    for _ in range(steps):
        m = max(1, round(n))
        n = max(1.0, m * error_at(m) / error)
    return n


def paired(names: list[str], all_scenes: dict, targets: list[float], pairs: int = PAIRS,
           seeds: int = 2, ref_spp: int = REF_SPP) -> list[dict]:
    """The target loop's time over uniform sampling's at the same error, timed in pairs
    (``--paired``): per scene and target, the loop is run (seeds 7, 8, …) for its error e,
    uniform sampling's samples a pixel at e found (``equal_error_spp``, on the mean error of
    the same seeds), and then ``pairs`` times in turns the loop and uniform sampling at the
    whole counts either side of it, each a render of every seed (the order swapped every
    pair, so that a machine that slows down or speeds up weighs on both alike). A pair's
    uniform time is interpolated linearly between its two counts; its ratio is the loop's
    time over it. A frame of milliseconds is rendered as many times in a row as take
    ``SHORT`` seconds (at most ``MOST_RUNS``), the same number for both, and its time is their
    mean. Reported: the median pair's ratio and the least and greatest (the spread the
    machine's noise leaves), and the ratio of the best times. Returns the rows it prints."""
    from renderer.render import render_buffer
    from renderer.scene import load_scene
    from renderer.scene.compile import compile_scene

    def compiled(scene, material, spp, target):
        return [compile_scene(load_scene(scene_at(scene, material, spp, target, 7 + k)))
                for k in range(seeds)]

    def run(frames: list, repeat: int) -> float:
        start = time.perf_counter()
        for _ in range(repeat):
            for cs in frames:
                render_buffer(cs)
        return (time.perf_counter() - start) / repeat

    rows = []
    print(f"{'scene':<20} {'target':>7} {'mean spp':>8} {'err/target':>10} "
          f"{'uniform spp':>11} {'runs':>4} {'ratio median':>12} {'min':>6} {'max':>6} "
          f"{'best':>6}", flush=True)
    for name in names:
        scene, material = all_scenes[name]
        ref = scene_reference(name, scene, material, ref_spp)
        error_at = _uniform_error(lambda n, s=scene, m=material: compiled(s, m, n, None), ref)
        for target in targets:
            loop = compiled(scene, material, CAP, target)
            bufs = [render_buffer(cs) for cs in loop]  # (its error, and the kernels loaded)
            error = float(np.mean([rel_mse(b.mean().astype(np.float64), ref) for b in bufs]))
            spp = float(np.mean([b.count.mean() for b in bufs]))
            n = equal_error_spp(error_at, error, spp)
            lo = max(1, math.floor(n))
            counts = (lo,) if n == lo else (lo, lo + 1)
            uniform = {m: compiled(scene, material, m, None) for m in counts}
            run(uniform[lo], 1)
            repeat = int(np.clip(math.ceil(SHORT / max(run(loop, 1), 1e-6)), 1, MOST_RUNS))
            loop_t, uniform_t = [], []
            for p in range(pairs):
                sides = ["loop", "uniform"] if p % 2 == 0 else ["uniform", "loop"]
                for side in sides:
                    if side == "loop":
                        loop_t.append(run(loop, repeat))
                    else:
                        t = [run(uniform[m], repeat) for m in counts]
                        uniform_t.append(t[0] if len(t) == 1
                                         else t[0] + (n - lo) * (t[1] - t[0]))
            ratio = np.array(loop_t) / np.array(uniform_t)
            row = {"scene": name, "target": target, "seeds": seeds, "mean_spp": spp,
                   "rel_mse": error, "ratio": error / target, "uniform_spp": n,
                   "runs": repeat, "pairs": pairs, "time_ratio": float(np.median(ratio)),
                   "time_ratio_min": float(ratio.min()), "time_ratio_max": float(ratio.max()),
                   "time_ratio_best": min(loop_t) / min(uniform_t)}
            rows.append(row)
            print(f"{name:<20} {target:>7} {spp:>8.0f} {error / target:>10.2f} {n:>11.1f} "
                  f"{repeat:>4} {row['time_ratio']:>12.2f} {ratio.min():>6.2f} "
                  f"{ratio.max():>6.2f} {row['time_ratio_best']:>6.2f}", flush=True)
    return rows


SPREAD_SEEDS = 32
# A single run's error/target should lie in [0.5, 1.1] (the range)
IN_RANGE = (0.5, 1.1)


def spread(names: list[str], all_scenes: dict, targets: list[float], seeds: int = SPREAD_SEEDS,
           ref_spp: int = REF_SPP) -> list[dict]:
    """How far the target loop's achieved error lands from the target, over ``seeds`` runs
    (seeds 7, 8, …) of each scene and target, untimed (``--spread``): the mean error/target, the
    frame's expected relMSE over the target (what ``render.target_error`` asks to be at most the
    target; its standard error over the seeds beside it), and single runs' median, 10th and 90th
    percentiles, extremes and share within ``IN_RANGE``. A run's error at a few samples a pixel
    is itself noisy (rare bright paths), so two seeds, the timed table's, can put a row's mean on
    either side of 0.5 where its expectation is not. Returns the rows it prints."""
    from renderer.render import render_buffer
    from renderer.scene import load_scene
    from renderer.scene.compile import compile_scene

    rows = []
    print(f"{'scene':<20} {'target':>7} {'seeds':>5} {'mean spp':>8} {'err/target':>10} "
          f"{'± s.e.':>6} {'median':>6} {'p10':>5} {'p90':>5} {'min':>5} {'max':>5} "
          f"{'in range':>8}", flush=True)
    for name in names:
        scene, material = all_scenes[name]
        ref = scene_reference(name, scene, material, ref_spp)
        for target in targets:
            ratios, spps = [], []
            for k in range(seeds):
                buf = render_buffer(compile_scene(load_scene(
                    scene_at(scene, material, CAP, target, 7 + k))))
                ratios.append(rel_mse(buf.mean().astype(np.float64), ref) / target)
                spps.append(float(buf.count.mean()))
            r = np.array(ratios)
            se = float(r.std(ddof=1) / math.sqrt(r.size)) if r.size > 1 else math.nan
            p10, median, p90 = (float(q) for q in np.percentile(r, [10, 50, 90]))
            row = {"scene": name, "target": target, "seeds": seeds,
                   "mean_spp": float(np.mean(spps)), "ratio": float(r.mean()),
                   "ratio_se": se, "ratio_median": median, "ratio_p10": p10,
                   "ratio_p90": p90, "ratio_min": float(r.min()), "ratio_max": float(r.max()),
                   "in_range": float(np.mean((r >= IN_RANGE[0]) & (r <= IN_RANGE[1])))}
            rows.append(row)
            print(f"{name:<20} {target:>7} {seeds:>5} {row['mean_spp']:>8.1f} "
                  f"{row['ratio']:>10.2f} {se:>6.2f} {median:>6.2f} {p10:>5.2f} {p90:>5.2f} "
                  f"{row['ratio_min']:>5.2f} {row['ratio_max']:>5.2f} "
                  f"{row['in_range']:>8.0%}", flush=True)
    means = np.array([r["ratio"] for r in rows])
    print(f"mean error/target {means.min():.2f}–{means.max():.2f} "
          f"({int(np.sum((means >= IN_RANGE[0]) & (means <= IN_RANGE[1])))} of {means.size} "
          f"in [{IN_RANGE[0]}, {IN_RANGE[1]}]); single runs in range: "
          f"{np.mean([r['in_range'] for r in rows]):.0%} on average", flush=True)
    return rows


def _uniform_error(frames, ref: np.ndarray):
    """``error_at(n)`` for ``equal_error_spp``: the mean relMSE of uniform renders of
    ``frames(n)`` (the scene at n spp, one compiled scene a seed) against ``ref``, each count
    rendered once."""
    from renderer.render import render_buffer

    known: dict[int, float] = {}

    def error_at(n: int) -> float:
        if n not in known:
            known[n] = float(np.mean([rel_mse(render_buffer(cs).mean().astype(np.float64), ref)
                                      for cs in frames(n)]))
        return known[n]

    return error_at


@contextlib.contextmanager
def embedded_farm():
    """An embedded Redis, one worker node of 2 processes and the API in process, for ``farm``
    and ``farm_frames``: yields ``(run, store)``, ``run(body)`` submitting a job (the API's
    body: the scene, its tile size, …) and returning its answer once it has ended and the
    seconds from submission to then. Done jobs keep their tiles in Redis (the frames are read
    from them)."""
    import os

    import redis
    from fastapi.testclient import TestClient

    from services.api.main import create_app
    from services.farm.settings import Settings
    from services.farm.store import JobStore
    from services.launcher import EmbeddedRedis, start_worker, terminate

    server = EmbeddedRedis().start()
    settings = Settings(redis_url=server.url, key_prefix="bench", archive_done=False)
    proc = start_worker(server.url, 2, 1, log=open(os.devnull, "w"),
                        extra_env={"LUCENT_KEY_PREFIX": "bench"})
    store = JobStore(redis.Redis.from_url(server.url), "bench")
    try:
        while sum(w.get("state") == "idle" for w in store.workers()) < 2:
            time.sleep(0.2)
        with TestClient(create_app(settings)) as client:
            def run(body: dict) -> tuple[dict, float]:
                t = time.perf_counter()
                answer = client.post("/api/jobs", json=body)
                assert answer.status_code < 300, answer.text
                job_id = answer.json()["id"]
                while (job := client.get(f"/api/jobs/{job_id}").json())["status"] not in (
                        "done", "failed", "cancelled"):
                    time.sleep(0.05)
                return job, time.perf_counter() - t

            yield run, store
    finally:
        terminate(proc, 30)
        store.r.close()
        server.stop()


def farm(names: list[str], all_scenes: dict, targets: list[float], seeds: int = 1) -> int:
    """Each scene and target as a farm job (``embedded_farm``: tiles of 16 px, passes growing
    from 8 spp): the achieved relMSE of the merged frame against the reference, the job's
    reported ``expected_error``, the mean samples a pixel, the wall time from submission to
    done. With ``seeds`` > 1 a job of each of the seeds 7, 8, … (a row each, the seed beside the
    scene) and a row of their means: one job's error is noisy where rare bright paths carry the
    image (the caustic floor)."""
    from services.farm.merge import assemble

    print(f"{'scene':<20} {'target':>7} {'mean spp':>8} {'seconds':>8} {'relMSE':>9} "
          f"{'err/target':>10} {'reported':>9}", flush=True)
    with embedded_farm() as (run, store):
        for name in names:
            scene, material = all_scenes[name]
            ref = scene_reference(name, scene, material)
            # (compiles in both processes)
            run({"scene": scene_at(scene, material, 8, None), "tile_size": 16})
            for target in targets:
                rows = []
                for k in range(seeds):
                    job, seconds = run({"scene": scene_at(scene, material, CAP, target, 7 + k),
                                        "tile_size": 16})
                    assembled = assemble(store, job["id"])
                    assert assembled is not None and job["status"] == "done", job
                    buf = assembled[0]
                    e = rel_mse(buf.mean().astype(np.float64), ref)
                    rows.append((float(buf.count.mean()), seconds, e, job["expected_error"]))
                    label = name if seeds == 1 else f"{name} s{7 + k}"
                    print(f"{label:<20} {target:>7} {rows[-1][0]:>8.0f} {seconds:>8.2f} "
                          f"{e:>9.5f} {e / target:>10.2f} {job['expected_error']:>9.5f}",
                          flush=True)
                    store.delete_job(job["id"])
                if seeds > 1:
                    spp, seconds, e, reported = (float(np.mean(c))
                                                 for c in zip(*rows, strict=True))
                    ratios = np.array([r[2] for r in rows]) / target
                    print(f"{name + ' mean':<20} {target:>7} {spp:>8.0f} {seconds:>8.2f} "
                          f"{e:>9.5f} {e / target:>10.2f} {reported:>9.5f}  (± "
                          f"{ratios.std(ddof=1) / math.sqrt(seeds):.2f}; "
                          f"{int(np.sum((ratios >= IN_RANGE[0]) & (ratios <= IN_RANGE[1])))}"
                          f" of {seeds} jobs in range)", flush=True)
    return 0


def frames_patch(first: dict, then: dict) -> list[dict]:
    """The JSON Patch that makes the scene ``then`` of the scene ``first`` (every top-level
    field replaced, added or removed): a frame of a job whose scene is ``first``."""
    return ([{"op": "replace" if key in first else "add", "path": "/" + key, "value": value}
             for key, value in then.items()]
            + [{"op": "remove", "path": "/" + key} for key in first if key not in then])


def farm_frames(names: list[str], all_scenes: dict, targets: list[float],
                seeds: int = 1) -> int:
    """A job of frames, one frame a scene of ``names`` (same film), for each target and seed
    (``--farm-frames``, ``embedded_farm``): each frame's achieved relMSE / target against its
    reference, its mean samples a pixel and the error the job reports for it
    (``frame_progress``). With a target each frame should land in [0.5, 1.1] × it, as the same
    scene alone does: the job samples each frame on its own sums."""
    from services.farm.merge import assemble

    refs = [scene_reference(n, *all_scenes[n]) for n in names]
    print(f"{'target':>7} {'seed':>4} {'seconds':>8}  "
          + "  ".join(f"{n + ' spp, err/target (reported)':>44}" for n in names), flush=True)
    with embedded_farm() as (run, store):
        def body(spp: int, target: float | None, seed: int) -> dict:
            scenes = [scene_at(*all_scenes[n], spp, target, seed) for n in names]
            return {"scene": scenes[0], "tile_size": 16,
                    "frames": [[]] + [frames_patch(scenes[0], s) for s in scenes[1:]]}

        run(body(8, None, 7))  # (compiles every frame in both processes)
        for target in targets:
            for k in range(seeds):
                job, seconds = run(body(CAP, target, 7 + k))
                assert job["status"] == "done", job
                cells = []
                for f, frame in enumerate(job["frame_progress"]):
                    assembled = assemble(store, job["id"], f)
                    assert assembled is not None
                    buf = assembled[0]
                    e = rel_mse(buf.mean().astype(np.float64), refs[f])
                    cells.append(f"{float(buf.count.mean()):>8.0f} {e / target:>6.2f} "
                                 f"({frame['expected_error'] / target:.2f})")
                print(f"{target:>7} {7 + k:>4} {seconds:>8.2f}  "
                      + "  ".join(f"{c:>44}" for c in cells), flush=True)
                store.delete_job(job["id"])
    return 0


def chart(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    for i, name in enumerate(dict.fromkeys(r["scene"] for r in rows)):
        mine = [r for r in rows if r["scene"] == name]
        x = [r["target"] for r in mine]
        # the colour cycle has 10 colours: the scenes after them dashed, square markers
        style = "o-" if i < 10 else "s--"
        a.plot(x, [r["ratio"] for r in mine], style, label=name)
        b.plot(x, [r["time_ratio"] for r in mine], style, label=name)
    for ax in (a, b):
        ax.set_xscale("log")
        ax.set_xlabel("render.target_error")
        ax.grid(True, which="both", alpha=0.3)
    a.axhspan(0.5, 1.1, color="green", alpha=0.1)
    a.set_ylabel("achieved relMSE / target")
    a.set_title("achieved error / target (band: 0.5–1.1)")
    b.axhline(1.0, color="k", lw=0.8)
    b.set_yscale("log")
    b.set_ylabel("time / uniform time at equal error")
    b.set_title("time against uniform sampling (below 1: faster)")
    b.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    raise SystemExit(main())
