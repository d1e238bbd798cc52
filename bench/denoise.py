"""Denoising as a point on the speed–accuracy chart: Open Image Denoise on N spp against
undenoised uniform sampling at the same time.

    .venv/bin/python -m bench.denoise [--scenes ...] [--spp 4 16 64 256 1024] [--repeat 2]
                                      [--out CSV] [--chart PNG]
    .venv/bin/python -m bench.denoise --from-csv CSV [--chart PNG]

Scenes at 64×48 with converged Mitsuba 3 references (``bench.target_error.scenes``): the chart
suite (wax sphere, backlit slab, concave torus, thin shell, spheres at albedo 0.5/0.9/0.99,
``volumetric``, volpath references at 16384 spp, committed or rendered once and cached) and the
glass sphere in the Cornell box (a caustic; its reference in tests/data). Each is rendered
uniformly at 4 … 1024 spp (wall time of ``render_buffer``, best of ``--repeat`` after a warm-up)
and, for each N of ``--spp``, rendered at N spp, its albedo and normal AOVs traced (8 rays a
pixel) and denoised (``renderer.film.denoise``, OIDN RT, HDR); its time is the three together.
"uniform at equal time" is the uniform relMSE at that time, interpolated on the uniform log–log
curve (slope −1 beyond its ends), and "spp" the samples a pixel uniform sampling affords in it.
The error is the chart suite's relMSE, mean((x − ref)²/(ref² + 0.01)), over the frame, and over
the "edge" pixels: the tenth of the frame where the reference's luminance changes fastest (what a
denoiser blurs). "gain" is uniform sampling's error at equal time over the denoised one (above 1:
the denoised image is closer to the reference); the last table gives the gains alone, frame ·
edges. ``--out`` writes every row to a CSV, ``--chart`` draws error against time per scene,
``--from-csv`` reprints the tables (and redraws the chart) from a CSV without rendering.
"""

from __future__ import annotations

import argparse
import csv
import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from bench.accuracy import _loglog, rel_mse, suite
from bench.target_error import scene_at, scene_reference, scenes

UNIFORM_SPP = (4, 16, 64, 256, 1024)
DENOISED_SPP = (4, 16, 64, 256, 1024)
DEFAULT = (*suite(), "glass_sphere")
AOV_SPP = 8  # as `lucent render --denoise`
FIELDS = ("scene", "kind", "spp", "seconds", "rel_mse", "edges", "uniform_spp",
          "uniform_rel_mse", "uniform_edges")

# (scene dict, repeat, denoised) -> (best wall time, image)
Runner = Callable[[dict, int, bool], tuple[float, np.ndarray]]


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


def measure(name: str, scene: dict, material: str | None, ref: np.ndarray,
            denoised_spp: list[int], repeat: int, runner: Runner = run) -> list[dict]:
    """One scene's rows: uniform sampling at each of ``UNIFORM_SPP`` (kind "uniform"), then
    each N of ``denoised_spp`` denoised (kind "denoised") with uniform sampling's spp and errors
    at its time (the uniform_* fields, NaN on the uniform rows)."""
    edges = edge_mask(ref)
    runner(scene_at(scene, material, 1, None), 1, True)  # warm the JIT and OIDN
    rows = []
    for spp in UNIFORM_SPP:
        t, img = runner(scene_at(scene, material, spp, None), repeat, False)
        rows.append({"scene": name, "kind": "uniform", "spp": spp, "seconds": t,
                     "rel_mse": rel_mse(img, ref), "edges": rel_mse(img, ref, edges),
                     "uniform_spp": math.nan, "uniform_rel_mse": math.nan,
                     "uniform_edges": math.nan})
    ts = np.array([r["seconds"] for r in rows])
    ue = np.array([r["rel_mse"] for r in rows])
    ux = np.array([r["edges"] for r in rows])
    for spp in denoised_spp:
        t, img = runner(scene_at(scene, material, spp, None), repeat, True)
        rows.append({"scene": name, "kind": "denoised", "spp": spp, "seconds": t,
                     "rel_mse": rel_mse(img, ref), "edges": rel_mse(img, ref, edges),
                     "uniform_spp": spp_at(t, ts, np.array(UNIFORM_SPP, float)),
                     "uniform_rel_mse": _loglog(t, ts, ue), "uniform_edges": _loglog(t, ts, ux)})
    return rows


def write_csv(rows: list[dict], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=FIELDS)
        writer.writeheader()
        writer.writerows(rows)


def read_csv(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return [{k: (v if k in ("scene", "kind") else int(v) if k == "spp" else float(v))
                 for k, v in row.items()} for row in csv.DictReader(f)]


def _gains(r: dict) -> tuple[float, float]:
    """A denoised row's gains, frame and edges: uniform sampling's error at equal time over its."""
    return r["uniform_rel_mse"] / r["rel_mse"], r["uniform_edges"] / r["edges"]


def table(rows: list[dict]) -> str:
    """The denoised rows as a Markdown table, with the uniform error at equal time and the
    gains (uniform over denoised: above 1, denoising is closer to the reference)."""
    lines = ["| scene | N spp | s | relMSE denoised | edges | uniform spp at equal time | "
             "relMSE uniform | edges | gain | gain on edges |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        if r["kind"] != "denoised":
            continue
        frame, edges = _gains(r)
        lines.append(
            f"| {r['scene']} | {r['spp']} | {r['seconds']:.3f} | {r['rel_mse']:.3g} | "
            f"{r['edges']:.3g} | {r['uniform_spp']:.0f} | {r['uniform_rel_mse']:.3g} | "
            f"{r['uniform_edges']:.3g} | {frame:.3g} | {edges:.3g} |")
    return "\n".join(lines)


def gains(rows: list[dict]) -> str:
    """A Markdown table of the gains alone, a scene a row and an N spp a column: "frame · edges",
    uniform sampling's error at equal time over the denoised one's (below 1: denoising is
    further from the reference)."""
    spp = list(dict.fromkeys(r["spp"] for r in rows if r["kind"] == "denoised"))
    lines = ["| scene | " + " | ".join(f"{n} spp" for n in spp) + " |",
             "|---|" + "---:|" * len(spp)]
    for name in dict.fromkeys(r["scene"] for r in rows):
        cells = {r["spp"]: "{:.3g} · {:.3g}".format(*_gains(r))
                 for r in rows if r["scene"] == name and r["kind"] == "denoised"}
        lines.append(f"| {name} | " + " | ".join(cells.get(n, "") for n in spp) + " |")
    return "\n".join(lines)


def chart(rows: list[dict], path: Path) -> None:
    """relMSE against seconds per scene, log–log: uniform sampling's curve and the denoised
    points (each labelled with its N spp), over the frame (solid) and its edges (dashed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(dict.fromkeys(r["scene"] for r in rows))
    cols = min(4, len(names))
    nrows = math.ceil(len(names) / cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(3.4 * cols, 3.0 * nrows), squeeze=False)
    for ax, name in zip(axes.flat, names, strict=False):
        for kind, colour, marker in (("uniform", "C0", "o"), ("denoised", "C3", "^")):
            mine = [r for r in rows if r["scene"] == name and r["kind"] == kind]
            t = [r["seconds"] for r in mine]
            ax.plot(t, [r["rel_mse"] for r in mine], marker + "-", color=colour,
                    label=f"{kind}, frame")
            ax.plot(t, [r["edges"] for r in mine], marker + "--", color=colour, alpha=0.55,
                    label=f"{kind}, edges")
            if kind == "denoised":
                for i, r in enumerate(mine):
                    last = i == len(mine) - 1  # (its label left of it, inside the axes)
                    ax.annotate(str(r["spp"]), (r["seconds"], r["rel_mse"]), fontsize=7,
                                xytext=(-3 if last else 3, -9), textcoords="offset points",
                                ha="right" if last else "left", color=colour)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(name, fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.tick_params(labelsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("seconds", fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel("relMSE", fontsize=8)
    for ax in list(axes.flat)[len(names):]:
        ax.axis("off")
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8)
    fig.suptitle("Open Image Denoise on N spp (labelled) against uniform sampling: "
                 "relMSE over the frame and its edges against time", fontsize=10)
    fig.tight_layout(rect=(0, 0.05, 1, 0.96))
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    all_scenes = scenes()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=list(DEFAULT), choices=list(all_scenes))
    parser.add_argument("--spp", nargs="+", type=int, default=list(DENOISED_SPP))
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--out", type=Path, default=None, help="write the rows to this CSV")
    parser.add_argument("--chart", type=Path, default=None, help="draw the chart to this PNG")
    parser.add_argument("--from-csv", type=Path, default=None,
                        help="render nothing: print the table (and draw --chart) from this CSV")
    args = parser.parse_args(argv)
    if args.from_csv is not None:
        rows = read_csv(args.from_csv)
    else:
        from renderer.film.denoise import MISSING, oidn_available

        if not oidn_available():
            print(MISSING)
            return 2
        rows = []
        for name in args.scenes:
            scene, material = all_scenes[name]
            mine = measure(name, scene, material, scene_reference(name, scene, material),
                           args.spp, args.repeat)
            rows += mine
            print(f"{name}: uniform " + ", ".join(
                f"{r['spp']} spp {r['seconds']:.3f} s {r['rel_mse']:.5f}/{r['edges']:.5f}"
                for r in mine if r["kind"] == "uniform"), flush=True)
        if args.out is not None:
            write_csv(rows, args.out)
    print(table(rows))
    print()
    print(gains(rows))
    if args.chart is not None:
        chart(rows, args.chart)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
