"""Failure map: every translucent method in a white furnace, over albedo × optical size × g × ior.

    .venv/bin/python -m bench.failure_map [--quick] [--out docs/images/accuracy/failure_map.png]

The scene is a sphere of radius 1 at the origin, seen from z = 4 (fov 40°, the sphere fills most
of the frame), under a uniform white background of radiance 1 and nothing else. With albedo ≤ 1
nothing in it emits, so every pixel is ≤ 1 in expectation (the furnace bound; = 1 at albedo 1 for
a method that conserves energy). The optical size is density × radius (radius 1, so it is the
density σt). For every method and grid cell it records:

- ``dropped``: samples whose radiance was NaN or ±Inf (``SampleBuffer.dropped``);
- ``object_mean``: the mean radiance of the pixels that see the sphere, and ``z_excess``, how many
  standard errors (from ``SampleBuffer.variance_of_mean``) the frame mean lies above 1 (energy
  gain beyond noise when > 6; frame and not per pixel, so that one heavy-tailed pixel among many
  cannot fake a gain);
- ``ratio``: ``object_mean`` over ``volumetric``'s at the same cell (volumetric is unbiased, so
  this is the method's bias in the furnace, up to volumetric's noise);
- ``us_per_sample``: wall time over samples (warm JIT), in microseconds.

It writes a CSV next to the PNG and the PNG itself: for each method, a heatmap of the ratio and
one of the time per sample, rows albedo × optical size, columns g × ior; cells with dropped
samples are marked "N", cells with energy gain beyond 6 SE "E".

``tests/renderer/test_failure_map.py`` runs a coarse 2×2×2×2 version of this sweep.
"""

from __future__ import annotations

import argparse
import csv
import itertools
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
METHODS = ("volumetric", "single_scatter", "diffuse_entry", "backlight", "diffusion")
RADIUS = 1.0

# The full grid and the coarse one the test runs
GRID = {
    "albedo": (0.5, 0.9, 0.99, 1.0),
    "optical_size": (0.3, 3.0, 30.0),
    "g": (-0.5, 0.0, 0.8),
    "ior": (1.0, 1.33, 1.6),
}
COARSE_GRID = {"albedo": (0.5, 1.0), "optical_size": (0.5, 20.0), "g": (0.0, 0.8),
               "ior": (1.0, 1.5)}


def furnace_scene(method: str, albedo: float, optical_size: float, g: float, ior: float,
                  size: int = 16, spp: int = 16, seed: int = 3) -> dict:
    """A translucent sphere alone under a white sky (the white furnace)."""
    return {
        "camera": {"position": [0, 0, 4], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 40.0},
        "film": {"width": size, "height": size},
        "render": {"spp": spp, "max_depth": -1, "seed": seed},
        "background": [1.0, 1.0, 1.0],
        "materials": {
            "m": {"type": "translucent", "method": method, "ior": ior, "albedo": [albedo] * 3,
                  "density": optical_size / RADIUS, "g": g},
        },
        "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": RADIUS, "material": "m"}],
    }


def sphere_mask(size: int) -> np.ndarray:
    """Pixels whose centre ray hits the sphere (pinhole camera at z = 4, vertical fov 40°)."""
    half = np.tan(np.radians(20.0))
    c = (np.arange(size) + 0.5) / size * 2 - 1
    x, y = np.meshgrid(c * half, -c * half)
    d = np.stack([x, y, -np.ones_like(x)], -1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    # |o + t d|² = R² with o = (0, 0, 4): discriminant of t² + 2 (o·d) t + |o|² − R²
    b = 4.0 * d[..., 2]
    return b * b - (16.0 - RADIUS**2) > 0


def measure(scene: dict) -> dict:
    """Render one furnace scene and the numbers the map records."""
    from renderer.render import render_buffer
    from renderer.scene import load_scene
    from renderer.scene.compile import compile_scene

    cs = compile_scene(load_scene(scene))
    start = time.perf_counter()
    buf = render_buffer(cs)
    seconds = time.perf_counter() - start
    mean = buf.mean().astype(np.float64)[..., 0]  # grey albedo: the channels agree
    var = buf.variance_of_mean()[..., 0]
    n_pix = mean.size
    frame_mean = float(mean.mean())
    frame_se = float(np.sqrt(var.sum()) / n_pix)
    mask = sphere_mask(mean.shape[0])
    samples = int(buf.count.sum())
    return {
        "dropped": buf.total_dropped,
        "samples": samples,
        "complete": bool(np.all(buf.count + buf.dropped >= cs.spp)),
        "frame_mean": frame_mean,
        "frame_se": frame_se,
        "z_excess": (frame_mean - 1.0) / frame_se if frame_se > 0 else
        (np.inf if frame_mean > 1.0 + 1e-6 else 0.0),
        "object_mean": float(mean[mask].mean()),
        "max_pixel": float(mean.max()),
        "seconds": seconds,
        "us_per_sample": 1e6 * seconds / max(samples, 1),
    }


def sweep(grid: dict, methods=METHODS, size: int = 16, spp: int = 16,
          progress: bool = False) -> list[dict]:
    from renderer.render import render_buffer

    rows = []
    for method in methods:
        render_buffer(furnace_scene(method, 0.9, 1.0, 0.0, 1.3, 4, 1))  # warm the JIT
        for albedo, optical_size, g, ior in itertools.product(*grid.values()):
            row = {"method": method, "albedo": albedo, "optical_size": optical_size, "g": g,
                   "ior": ior}
            row.update(measure(furnace_scene(method, albedo, optical_size, g, ior, size, spp)))
            rows.append(row)
            if progress:
                print(f"{method:<15} a={albedo:<5} tau={optical_size:<5} g={g:<5} ior={ior:<5} "
                      f"mean {row['object_mean']:.4f}  z {row['z_excess']:+6.2f}  "
                      f"dropped {row['dropped']}  {row['us_per_sample']:.1f} us/sample",
                      flush=True)
    # Bias against volumetric at the same cell
    key = ("albedo", "optical_size", "g", "ior")
    vol = {tuple(r[k] for k in key): r["object_mean"] for r in rows if r["method"] == "volumetric"}
    for r in rows:
        v = vol.get(tuple(r[k] for k in key))
        r["ratio"] = r["object_mean"] / v if v else float("nan")
    return rows


def draw(rows: list[dict], grid: dict, path: Path, note: str = "") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm, TwoSlopeNorm

    methods = list(dict.fromkeys(r["method"] for r in rows))
    ylabels = [f"a {a}, τ {t:g}" for a in grid["albedo"] for t in grid["optical_size"]]
    xlabels = [f"g {g:g}\nη {i:g}" for g in grid["g"] for i in grid["ior"]]
    ny, nx = len(ylabels), len(xlabels)

    def table(method: str, field: str) -> np.ndarray:
        out = np.full((ny, nx), np.nan)
        for r in rows:
            if r["method"] != method:
                continue
            y = grid["albedo"].index(r["albedo"]) * len(grid["optical_size"]) + \
                grid["optical_size"].index(r["optical_size"])
            x = grid["g"].index(r["g"]) * len(grid["ior"]) + grid["ior"].index(r["ior"])
            out[y, x] = r[field]
        return out

    us = np.array([r["us_per_sample"] for r in rows])
    fig, axes = plt.subplots(2, len(methods), figsize=(3.3 * len(methods), 2 * (0.32 * ny + 1.6)),
                             constrained_layout=True, squeeze=False)
    ratio_norm = TwoSlopeNorm(vcenter=1.0, vmin=0.0, vmax=2.0)
    time_norm = LogNorm(vmin=max(us.min(), 1e-3), vmax=us.max())
    for col, method in enumerate(methods):
        ratio, dropped, z = (table(method, f) for f in ("ratio", "dropped", "z_excess"))
        im0 = axes[0, col].imshow(np.clip(ratio, 0, 2), cmap="RdBu_r", norm=ratio_norm,
                                  aspect="auto")
        im1 = axes[1, col].imshow(table(method, "us_per_sample"), cmap="viridis", norm=time_norm,
                                  aspect="auto")
        for y, x in itertools.product(range(ny), range(nx)):
            mark = ("N" if dropped[y, x] > 0 else "") + ("E" if z[y, x] > 6 else "")
            text = mark or f"{ratio[y, x]:.2f}"
            axes[0, col].text(x, y, text, ha="center", va="center", fontsize=5.5,
                              color="k" if not mark else "m", weight="bold" if mark else None)
        for row, title in ((0, "object mean / volumetric"), (1, "µs per sample")):
            ax = axes[row, col]
            ax.set_title(f"{method}\n{title}", fontsize=8)
            ax.set_xticks(range(nx), xlabels, fontsize=5.5)
            ax.set_yticks(range(ny), ylabels if col == 0 else [""] * ny, fontsize=6)
    fig.colorbar(im0, ax=axes[0, :].tolist(), shrink=0.8, label="ratio (1 = volumetric)")
    fig.colorbar(im1, ax=axes[1, :].tolist(), shrink=0.8, label="µs / sample")
    fig.suptitle("White furnace, sphere radius 1 under a white sky: a = albedo, τ = density × "
                 "radius, η = ior. N: NaN/Inf samples, E: frame mean > 1 + 6 SE. " + note,
                 fontsize=9)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the coarse grid of the test")
    parser.add_argument("--size", type=int, default=16, help="film width = height")
    parser.add_argument("--spp", type=int, default=32)
    parser.add_argument("--out", type=Path,
                        default=ROOT / "docs" / "images" / "accuracy" / "failure_map.png")
    args = parser.parse_args(argv)
    grid = COARSE_GRID if args.quick else GRID
    args.out.parent.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    rows = sweep(grid, size=args.size, spp=args.spp, progress=True)
    with open(args.out.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    draw(rows, grid, args.out, f"{args.size}×{args.size}, {args.spp} spp.")
    bad = [r for r in rows if r["dropped"] or r["z_excess"] > 6 or not r["complete"]]
    print(f"\n{len(rows)} cells in {time.perf_counter() - start:.0f} s; "
          f"{len(bad)} with NaN/Inf, energy gain or unfinished pixels")
    for r in bad:
        print("  ", {k: r[k] for k in ("method", "albedo", "optical_size", "g", "ior", "dropped",
                                       "frame_mean", "z_excess")})
    for method in METHODS:
        mine = [r for r in rows if r["method"] == method]
        us = [r["us_per_sample"] for r in mine]
        ratio = [r["ratio"] for r in mine]
        print(f"{method:<15} µs/sample {min(us):7.2f} – {max(us):8.2f}   "
              f"object mean / volumetric {min(ratio):.3f} – {max(ratio):.3f}")
    print(f"wrote {args.out} and {args.out.with_suffix('.csv')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
