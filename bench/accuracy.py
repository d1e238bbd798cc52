"""Speed against accuracy: error against time for every translucent method, on a fixed suite.

    .venv/bin/python -m bench.accuracy [--quick] [--out docs/images/accuracy] [--from-csv]

Scenes (64×48): the wax sphere in a Cornell box (``examples/translucent_sphere.json``), the
backlit jade slab (``examples/backlit_slab.json``), a concave mesh, the soap torus lit from above
(``examples/translucent_torus.json``, 9216 triangles), a thin shell, a hollow sphere whose wall is
0.04 thick, optical thickness 0.8, in the Cornell box (``examples/translucent_shell.json``), and the
wax sphere with a grey albedo of 0.5, 0.9 and 0.99 (variants written below). Only
``material.method`` changes between runs.

Reference per scene: Mitsuba 3 ``volpath`` (``renderer.mitsuba_bridge``); the sphere and the slab
reuse ``tests/data/*_ref.npy`` (16384 spp), the others are rendered here at ``--ref-spp`` (16384)
and cached under ``$LUCENT_CACHE`` (default ``/tmp/lucent-accuracy``), never in git. Without
Mitsuba, Lucent's own ``volumetric`` at ``--ref-spp`` stands in (said in the output and the CSV).

For every method and spp in 4, 16, 64, 256, 1024 (seed 7) it records the wall time (best of two,
after a 1-spp render that warms the JIT) and these errors against the reference:

- relative MSE, mean((x − ref)² / (ref² + 0.01)) over pixels and channels (as bench.target_error),
  over the whole frame (``rel_mse``) and over the pixels that see the translucent object
  (``object_rel_mse``: the walls and floor are the same for every method, so their noise hides
  the methods' bias in the frame figure);
- 1 − SSIM (Wang et al. 2004: 11×11 Gaussian window σ = 1.5, K1 = 0.01, K2 = 0.03, L = 1,
  mean over the valid windows) on luminance Y = 0.2126 R + 0.7152 G + 0.0722 B, mapped to
  [0, 1) by Y / (1 + Y) (Reinhard), so that the light source does not set the dynamic range.

It writes ``results.csv``, one log–log chart per scene (``<scene>.png``: relMSE and 1 − SSIM
against seconds, one line per method) and ``failures.md``, the "where each method fails" table:

- floor: the method's object relMSE at its highest spp over volumetric's relMSE at the same time
  (log–log interpolation on volumetric's curve; beyond its ends, extended with slope −1,
  the Monte Carlo rate); > 1 means volumetric is more accurate for that time;
- crossover: the first time at which volumetric's interpolated error falls below the method's
  (within the times both measured); "never" if it does not, "always" if it already does at the
  first common time.

``auto.csv`` / ``auto.md``: for every scene and a few object-relMSE targets (``AUTO_TARGETS``),
what ``method: "auto"`` chooses there and the seconds that choice and ``volumetric`` take to
reach the target, read off the measured curves (``time_to_target``); the claim to check is that
auto is never the slower. ``--from-csv`` renders nothing and rewrites the charts and the tables
from ``OUT/results.csv`` (after a change to auto's rule).

``--chromatic`` runs the chromatic suite instead (the wax sphere with σt 3/8/16 per channel, the
jade slab with 12/25/50, a sphere of the ``skin1`` preset, and the mixed-regime ``mixed_wax`` and
``mixed_slab``, blue made effectively opaque; references split by channel, three Mitsuba renders
with the medium grey at each channel's σt, in ``tests/data`` but for the skin) and writes to
``docs/images/accuracy/chromatic``; auto's ``CHROMATIC_FLOOR`` and ``MIXED_FLOOR`` come from it.
``--scenes NAME ...`` renders only those suite scenes and replaces their rows in results.csv.

``--quick`` (< 60 s; references at 1024 spp) renders spp 4, 16, 64 once each, only the sphere,
the slab and albedo 0.99, and writes to ``$LUCENT_CACHE/quick`` unless ``--out`` says otherwise.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
METHODS = ("volumetric", "single_scatter", "diffuse_entry", "backlight", "diffusion")
FILM = {"width": 64, "height": 48}
SEED = 7
CACHE = Path(os.environ.get("LUCENT_CACHE", "/tmp/lucent-accuracy"))


# --------------------------------------------------------------------------------------------------
# The suite
# --------------------------------------------------------------------------------------------------


def _example(name: str) -> dict:
    """An example at the suite's film size, its mesh files read into inline arrays (the renderers
    take scene dicts, where a server-style ``load_scene`` refuses paths)."""
    from renderer.geometry.meshio import read_mesh

    scene = json.loads((ROOT / "examples" / f"{name}.json").read_text())
    scene["film"] = dict(FILM)
    for obj in scene["objects"]:
        if obj["type"] == "mesh" and "path" in obj:
            vertices, triangles = read_mesh(ROOT / "examples" / obj.pop("path"))
            obj.update(vertices=vertices.tolist(), triangles=triangles.tolist())
    return scene


CHROMATIC_SUITE = {"chromatic_wax": "wax", "chromatic_slab": "jade", "skin_preset": "skin",
                   "mixed_wax": "wax", "mixed_slab": "jade"}
# Mixed-regime variants of the chromatic wax and jade (each channel in its own regime for auto,
# renderer/materials/auto.py): blue made effectively opaque at 64×48 (σt 1000, albedo 0.5: 99 % of
# its light leaves within 0.0032, under a pixel and a tenth of the object), red and green as they
# were (translucent: deep in red).
MIXED = {"mixed_wax": ("chromatic_wax", "wax", [0.97, 0.88, 0.5], [3.0, 8.0, 1000.0]),
         "mixed_slab": ("chromatic_slab", "jade", [0.6, 0.95, 0.5], [12.0, 25.0, 1000.0])}

# The spp of the references in tests/data that are not 16384
STORED_SPP = {"mixed_slab": 4096}


def _mixed(name: str) -> dict:
    base, material, albedo, density = MIXED[name]
    scene = _example(base)
    scene["materials"][material].update(albedo=albedo, density=density)
    return scene


def suite(quick: bool = False, chromatic: bool = False) -> dict[str, tuple[dict, str]]:
    """Scene name → (scene dict at 64×48, name of its translucent material); ``chromatic``: the
    chromatic suite (the wax sphere at σt 3/8/16, the jade slab at 12/25/50, a skin1 sphere)."""
    if chromatic:
        return {name: (_mixed(name) if name in MIXED else _example(name), material)
                for name, material in CHROMATIC_SUITE.items()}
    scenes = {
        "translucent_sphere": (_example("translucent_sphere"), "wax"),
        "backlit_slab": (_example("backlit_slab"), "jade"),
    }
    if not quick:
        scenes["translucent_torus"] = (_example("translucent_torus"), "soap")
        scenes["translucent_shell"] = (_example("translucent_shell"), "eggshell")
    for albedo in (0.5, 0.9, 0.99):
        if quick and albedo != 0.99:
            continue
        scene = _example("translucent_sphere")
        scene["materials"]["wax"]["albedo"] = [albedo] * 3
        scenes[f"sphere_albedo_{albedo}"] = (scene, "wax")
    return scenes


def with_method(scene: dict, material: str, method: str, spp: int) -> dict:
    out = json.loads(json.dumps(scene))
    out["materials"][material]["method"] = method
    out["render"].update(spp=spp, seed=SEED)
    return out


# --------------------------------------------------------------------------------------------------
# References
# --------------------------------------------------------------------------------------------------


def reference(name: str, scene: dict, material: str, spp: int,
              committed: bool = True) -> tuple[np.ndarray, str]:
    """The converged image of ``scene`` (its ``volumetric`` form) and where it came from: the
    committed one in tests/data for a stock scene (whatever ``spp``, unless ``committed`` is
    False), else Mitsuba's at ``spp``, cached."""
    scene = with_method(scene, material, "volumetric", spp)
    stored = ROOT / "tests" / "data" / f"{name}_ref.npy"
    stock = ((_mixed(name) if name in MIXED else _example(name))
             if committed and stored.exists() else None)
    if stock is not None and scene == with_method(stock, material, "volumetric", spp):
        split = " split by channel" if name in CHROMATIC_SUITE else ""
        return (np.load(stored).astype(np.float64),
                f"mitsuba volpath {STORED_SPP.get(name, 16384)} spp{split} (tests/data)")
    key = hashlib.sha256(json.dumps(scene, sort_keys=True).encode()).hexdigest()[:16]
    try:
        import mitsuba  # noqa: F401  (fail here, not half-way through a render)

        from renderer.mitsuba_bridge import is_chromatic, render_mitsuba, render_mitsuba_split

        if is_chromatic(scene):
            # RGB volpath is no reference for a chromatic medium: split by channel
            source = f"mitsuba volpath {spp} spp split by channel"
            render_ref = lambda: render_mitsuba_split(scene, spp, 0)  # noqa: E731
        else:
            source = f"mitsuba volpath {spp} spp"
            render_ref = lambda: render_mitsuba(scene, spp, 0)  # noqa: E731
    except ImportError:
        from renderer.render import render

        source, render_ref = f"lucent volumetric {spp} spp", lambda: render(scene, spp)
    path = CACHE / f"{name}-{key}-{source.split()[0]}.npy"
    if path.exists():
        return np.load(path).astype(np.float64), source + " (cached)"
    CACHE.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    img = np.asarray(render_ref(), dtype=np.float32)
    print(f"  reference {name}: {source}, {time.perf_counter() - start:.1f} s -> {path}")
    np.save(path, img)
    return img.astype(np.float64), source


# --------------------------------------------------------------------------------------------------
# Error metrics
# --------------------------------------------------------------------------------------------------


def rel_mse(img: np.ndarray, ref: np.ndarray, mask: np.ndarray | None = None) -> float:
    err = (img - ref) ** 2 / (ref**2 + 0.01)
    return float(np.mean(err if mask is None else err[mask]))


def object_mask(scene: dict, material: str) -> np.ndarray:
    """Pixels whose camera ray hits the translucent object first (as docs/methods/make_images.py):
    the object alone emits, everything is black, max_depth 0."""
    from renderer.render import render_buffer
    from renderer.scene import load_scene

    d = json.loads(json.dumps(scene))
    d["materials"] = {"black": {"type": "diffuse", "albedo": [0, 0, 0]}}
    for obj in d["objects"]:
        obj["emission"] = [1, 1, 1] if obj["material"] == material else None
        obj["material"] = "black"
    d["lights"] = []
    d["background"] = [0, 0, 0]
    d["render"].update(max_depth=0, target_error=None)
    return render_buffer(load_scene(d), 16).mean()[..., 0] > 0.99


def _gaussian_window(size: int = 11, sigma: float = 1.5) -> np.ndarray:
    x = np.arange(size) - (size - 1) / 2
    w = np.exp(-(x**2) / (2 * sigma**2))
    return w / w.sum()


def _filter_valid(img: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Separable 2-D filtering, 'valid' region only (as Wang et al.'s reference code)."""
    k = len(w)
    rows = sum(w[i] * img[i : img.shape[0] - k + 1 + i, :] for i in range(k))
    return sum(w[j] * rows[:, j : rows.shape[1] - k + 1 + j] for j in range(k))


def ssim(x: np.ndarray, y: np.ndarray, data_range: float = 1.0) -> float:
    """Mean SSIM of two greyscale images (Wang, Bovik, Sheikh, Simoncelli 2004, eq. 13)."""
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    w = _gaussian_window()
    mu_x, mu_y = _filter_valid(x, w), _filter_valid(y, w)
    sxx = _filter_valid(x * x, w) - mu_x**2
    syy = _filter_valid(y * y, w) - mu_y**2
    sxy = _filter_valid(x * y, w) - mu_x * mu_y
    num = (2 * mu_x * mu_y + c1) * (2 * sxy + c2)
    den = (mu_x**2 + mu_y**2 + c1) * (sxx + syy + c2)
    return float(np.mean(num / den))


def luminance_tonemapped(img: np.ndarray) -> np.ndarray:
    y = img @ np.array([0.2126, 0.7152, 0.0722])
    return y / (1.0 + y)


def ssim_error(img: np.ndarray, ref: np.ndarray) -> float:
    return 1.0 - ssim(luminance_tonemapped(img), luminance_tonemapped(ref))


# --------------------------------------------------------------------------------------------------
# Rendering and timing
# --------------------------------------------------------------------------------------------------


def timed_render(scene: dict, repeats: int) -> tuple[float, np.ndarray, int]:
    from renderer.render import render_buffer
    from renderer.scene import load_scene
    from renderer.scene.compile import compile_scene

    cs = compile_scene(load_scene(scene))
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        buf = render_buffer(cs)
        best = min(best, time.perf_counter() - start)
    return best, buf.mean().astype(np.float64), buf.total_dropped


# --------------------------------------------------------------------------------------------------
# The "where each method fails" table
# --------------------------------------------------------------------------------------------------


def _loglog(t: float, ts: np.ndarray, es: np.ndarray) -> float:
    """Error at time t on a measured curve (log–log linear; slope −1 beyond its ends)."""
    order = np.argsort(ts)
    lt, le = np.log(ts[order]), np.log(es[order])
    x = np.log(t)
    if x < lt[0]:
        return float(np.exp(le[0] - (x - lt[0])))
    if x > lt[-1]:
        return float(np.exp(le[-1] - (x - lt[-1])))
    return float(np.exp(np.interp(x, lt, le)))


def failure_rows(rows: list[dict], metric: str = "object_rel_mse") -> list[dict]:
    out = []
    for scene in dict.fromkeys(r["scene"] for r in rows):
        vol = [r for r in rows if r["scene"] == scene and r["method"] == "volumetric"]
        vt = np.array([r["seconds"] for r in vol])
        ve = np.array([r[metric] for r in vol])
        for method in METHODS[1:]:
            mine = sorted((r for r in rows if r["scene"] == scene and r["method"] == method),
                          key=lambda r: r["spp"])
            mt = np.array([r["seconds"] for r in mine])
            me = np.array([r[metric] for r in mine])
            floor = me[-1] / _loglog(mt[-1], vt, ve)
            # Crossover: first time (on a grid over the common range) where volumetric is better
            lo, hi = max(vt.min(), mt.min()), min(vt.max(), mt.max())
            crossover = "never"
            if lo < hi:
                for t in np.geomspace(lo, hi, 200):
                    if _loglog(t, vt, ve) < _loglog(t, mt, me):
                        crossover = "always" if t == lo else f"{t:.3g} s"
                        break
            else:
                crossover = "no overlap"
            out.append({"scene": scene, "method": method, "spp": mine[-1]["spp"],
                        "error": me[-1], "floor": floor, "crossover": crossover})
    return out


def failure_markdown(fails: list[dict]) -> str:
    scenes = list(dict.fromkeys(f["scene"] for f in fails))
    lines = [
        "| method | " + " | ".join(f"`{s}`" for s in scenes) + " |",
        "|---|" + "---|" * len(scenes),
    ]
    for method in METHODS[1:]:
        cells = []
        for s in scenes:
            f = next(f for f in fails if f["scene"] == s and f["method"] == method)
            cells.append(f"{f['error']:.3g} · ×{f['floor']:.3g} · {f['crossover']}")
        lines.append(f"| `{method}` | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------------------------------
# `auto` against `volumetric`: time to reach a target, read off the measured curves
# --------------------------------------------------------------------------------------------------

# Object relMSE targets: loose ones where auto takes an approximation, tight ones where it falls
# back to volumetric (at or above BIAS_FLOOR's largest value every approximation qualifies).
AUTO_TARGETS = (1.0, 0.6, 0.5, 0.45, 0.35, 0.3, 0.25, 0.1, 0.03)


def time_to_target(ts: np.ndarray, es: np.ndarray, target: float,
                   extrapolate: bool) -> tuple[float, str]:
    """First time at which a measured curve (by increasing spp) reaches ``target``, log–log
    interpolated between its points, and how it was read: "measured" (between two points),
    "first point" (already there at the fewest spp: an upper bound), "extrapolated" (slope −1
    beyond the last point, for an unbiased method) or "never" (inf: a biased curve that never got
    there)."""
    if es[0] <= target:
        return float(ts[0]), "first point"
    for k in range(1, len(ts)):
        if es[k] <= target:
            x = np.interp(np.log(target), np.log([es[k], es[k - 1]]),
                          np.log([ts[k], ts[k - 1]]))
            return float(np.exp(x)), "measured"
    if extrapolate:
        return float(ts[-1] * es[-1] / target), "extrapolated"
    return float("inf"), "never"


def _curve(rows: list[dict], scene: str, method: str, metric: str):
    mine = sorted((r for r in rows if r["scene"] == scene and r["method"] == method),
                  key=lambda r: r["spp"])
    return np.array([r["seconds"] for r in mine]), np.array([r[metric] for r in mine])


def auto_rows(rows: list[dict], scenes: dict[str, tuple[dict, str]],
              targets=AUTO_TARGETS, metric: str = "object_rel_mse") -> list[dict]:
    """For every suite scene and target: what ``auto`` chooses (the same ``auto_choice`` that
    ``compile_scene`` renders), and the time the chosen method and ``volumetric`` take to reach
    the target on their measured curves."""
    from renderer.materials.auto import auto_choice
    from renderer.scene import load_scene

    out = []
    for name, (scene, material) in scenes.items():
        vt, ve = _curve(rows, name, "volumetric", metric)
        for target in targets:
            d = with_method(scene, material, "auto", 1)
            d["render"]["target_error"] = target
            choice = auto_choice(load_scene(d), material)
            t_vol, how_vol = time_to_target(vt, ve, target, extrapolate=True)
            if choice.method == "volumetric":
                t_auto, how_auto = t_vol, how_vol
            else:
                at, ae = _curve(rows, name, choice.method, metric)
                t_auto, how_auto = time_to_target(at, ae, target, extrapolate=False)
            out.append({"scene": name, "target": target, "auto_method": choice.method,
                        "expected_error": choice.expected_error, "auto_seconds": t_auto,
                        "auto_read": how_auto, "volumetric_seconds": t_vol,
                        "volumetric_read": how_vol, "speedup": t_vol / t_auto,
                        "claim_holds": _claim(t_auto, how_auto, t_vol, how_vol)})
    return out


def _claim(t_auto: float, how_auto: str, t_vol: float, how_vol: str) -> str:
    """"yes" when auto reaches the target no later than volumetric; "tie" when auto's time is
    only an upper bound (already there at its first point, 4 spp: the curves say nothing finer)
    within 10 % of volumetric's; else "no"."""
    if t_auto <= t_vol:
        return "yes"
    if how_auto == "first point" and t_auto <= 1.1 * t_vol:
        return "tie"
    return "no"


def auto_markdown(autos: list[dict]) -> str:
    lines = ["| target | auto's choice | " + " | ".join(
        f"`{s}`" for s in dict.fromkeys(a["scene"] for a in autos)) + " |"]
    lines.append("|---|---|" + "---|" * (len(lines[0].split("|")) - 4))
    for target in dict.fromkeys(a["target"] for a in autos):
        mine = [a for a in autos if a["target"] == target]
        methods = sorted({a["auto_method"] for a in mine})
        cells = []
        for a in mine:
            if a["auto_method"] == "volumetric":
                cells.append(f"{a['volumetric_seconds']:.3g} s{_mark(a['volumetric_read'])}")
            else:
                cells.append(f"{a['auto_seconds']:.3g}{_mark(a['auto_read'])} / "
                             f"{a['volumetric_seconds']:.3g}{_mark(a['volumetric_read'])} s "
                             f"(×{a['speedup']:.3g})"
                             + {"yes": "", "tie": " tie", "no": " **fails**"}[a["claim_holds"]])
        lines.append(f"| {target:g} | {', '.join(methods)} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _mark(how: str) -> str:
    return {"measured": "", "first point": "≤", "extrapolated": "*", "never": " never"}[how]


def suggested_floors(rows: list[dict], metric: str = "object_rel_mse") -> dict[str, float]:
    """Each approximation's largest error at its highest spp over the suite: auto's BIAS_FLOOR."""
    out = {}
    for method in METHODS[1:]:
        top = max(r["spp"] for r in rows if r["method"] == method)
        out[method] = max(r[metric] for r in rows if r["method"] == method and r["spp"] == top)
    return out



# --------------------------------------------------------------------------------------------------
# Charts
# --------------------------------------------------------------------------------------------------


def chart(scene: str, rows: list[dict], source: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), constrained_layout=True)
    for ax, metric, label in ((axes[0], "rel_mse", "relative MSE, frame"),
                              (axes[1], "object_rel_mse", "relative MSE, object pixels"),
                              (axes[2], "ssim_error", "1 − SSIM (luminance), frame")):
        for method in METHODS:
            mine = sorted((r for r in rows if r["scene"] == scene and r["method"] == method),
                          key=lambda r: r["spp"])
            t = [r["seconds"] for r in mine]
            e = [max(r[metric], 1e-9) for r in mine]
            ax.loglog(t, e, "o-", label=method, lw=2 if method == "volumetric" else 1.2,
                      color="k" if method == "volumetric" else None, ms=4)
            ax.annotate(str(mine[-1]["spp"]), (t[-1], e[-1]), fontsize=7,
                        xytext=(3, 0), textcoords="offset points")
        ax.set_xlabel("wall time (s), 64×48, 2 cores")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"{scene} — reference: {source}", fontsize=10)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# --------------------------------------------------------------------------------------------------
# Main
# --------------------------------------------------------------------------------------------------


def read_rows(path: Path) -> list[dict]:
    """The rows of a results.csv, typed as ``main`` wrote them."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    for r in rows:
        r["spp"], r["dropped"] = int(r["spp"]), int(r["dropped"])
        for key in ("seconds", "rel_mse", "object_rel_mse", "ssim_error", "mean_over_ref"):
            r[key] = float(r[key])
    return rows


def write_csv(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def write_tables(rows: list[dict], scenes: dict[str, tuple[dict, str]], out: Path,
                 floors_of_auto: bool = True) -> None:
    """Charts, failures.md, the auto table (auto.csv, auto.md) from the measured rows;
    ``floors_of_auto``: the suite is the one auto's BIAS_FLOOR comes from (else the chromatic)."""
    sources = {r["scene"]: r["reference"] for r in rows}
    for name in sources:
        chart(name, rows, sources[name], out / f"{name}.png")
    table = failure_markdown(failure_rows(rows))
    floors = suggested_floors(rows)
    (out / "failures.md").write_text(
        "object relMSE at the highest spp · floor (× volumetric's relMSE at equal time) · "
        "crossover (time after which volumetric is more accurate)\n\n" + table
        + "\nLargest object relMSE at the highest spp"
        + (" (auto's BIAS_FLOOR): " if floors_of_auto
           else " (with the grey suite's, by regime: auto's CHROMATIC_FLOOR, MIXED_FLOOR): ")
        + ", ".join(f"{m} {e:.3g}" for m, e in floors.items()) + "\n")
    print("\n" + table)
    autos = auto_rows(rows, {k: v for k, v in scenes.items() if k in sources})
    write_csv(out / "auto.csv", autos)
    (out / "auto.md").write_text(
        "Seconds to reach each object-relMSE target on the measured curves: auto's choice / "
        "volumetric (×speed-up; tie: auto's time only bounded by its 4-spp time, within 10 %); "
        "one number where auto chose volumetric. ≤: reached at the "
        "first point (4 spp); *: extrapolated with slope −1 beyond volumetric's 1024 spp.\n\n"
        + auto_markdown(autos))
    print(auto_markdown(autos))
    print("largest floors: " + ", ".join(f"{m} {e:.3g}" for m, e in floors.items()))
    print(f"wrote {out}/results.csv, failures.md, auto.csv, auto.md and {len(sources)} charts")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="reduced suite, < 60 s")
    parser.add_argument("--ref-spp", type=int, default=None,
                        help="reference spp (16384; 1024 quick)")
    parser.add_argument("--out", type=Path, default=None,
                        help="docs/images/accuracy (quick: $LUCENT_CACHE/quick)")
    parser.add_argument("--chromatic", action="store_true",
                        help="the chromatic suite, to docs/images/accuracy/chromatic")
    parser.add_argument("--from-csv", action="store_true",
                        help="render nothing: redo the charts and tables from OUT/results.csv")
    parser.add_argument("--scenes", nargs="+", default=None,
                        help="only these suite scenes; their rows replace theirs in results.csv")
    args = parser.parse_args(argv)
    if args.out is None:
        args.out = CACHE / "quick" if args.quick else ROOT / "docs" / "images" / "accuracy"
        if args.chromatic:
            args.out = args.out / "chromatic"
    if args.from_csv:
        write_tables(read_rows(args.out / "results.csv"), suite(args.quick, args.chromatic),
                     args.out, floors_of_auto=not args.chromatic)
        return 0
    spps = (4, 16, 64) if args.quick else (4, 16, 64, 256, 1024)
    repeats = 1 if args.quick else 2
    ref_spp = args.ref_spp or (1024 if args.quick else 16384)
    args.out.mkdir(parents=True, exist_ok=True)

    import numba

    from renderer.render import render_buffer

    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"numba threads {numba.get_num_threads()}, python {platform.python_version()}")
    rows: list[dict] = []
    print(f"{'scene':<20} {'method':<15} {'spp':>5} {'seconds':>8} {'relMSE':>9} "
          f"{'obj relMSE':>9} {'1-SSIM':>8} {'mean/ref':>8}")
    scenes = suite(args.quick, args.chromatic)
    todo = {k: v for k, v in scenes.items() if args.scenes is None or k in args.scenes}
    if args.scenes is not None and (args.out / "results.csv").exists():
        rows = [r for r in read_rows(args.out / "results.csv") if r["scene"] not in todo]
    for name, (scene, material) in todo.items():
        ref, source = reference(name, scene, material, ref_spp)
        source = source.removesuffix(" (cached)")
        mask = object_mask(scene, material)
        for method in METHODS:
            render_buffer(with_method(scene, material, method, 1))  # warm the JIT
            for spp in spps:
                seconds, img, dropped = timed_render(
                    with_method(scene, material, method, spp), repeats)
                row = {"scene": name, "method": method, "spp": spp, "seconds": seconds,
                       "rel_mse": rel_mse(img, ref), "object_rel_mse": rel_mse(img, ref, mask),
                       "ssim_error": ssim_error(img, ref),
                       "mean_over_ref": float(img.mean() / ref.mean()), "dropped": dropped,
                       "reference": source}
                rows.append(row)
                print(f"{name:<20} {method:<15} {spp:>5} {seconds:>8.3f} {row['rel_mse']:>9.5f} "
                      f"{row['object_rel_mse']:>9.5f} {row['ssim_error']:>8.4f} "
                      f"{row['mean_over_ref']:>8.3f}")

    write_csv(args.out / "results.csv", rows)
    write_tables(rows, scenes, args.out, floors_of_auto=not args.chromatic)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
