"""`auto`'s "effectively opaque" regime, measured: the opaque surface against the random walk.

    .venv/bin/python -m bench.opaque [--spp 1024] [--ref-spp 2048] [--out docs/images/accuracy]

Dense spheres in the Cornell box of ``examples/translucent_sphere.json`` (64×48, like the accuracy
suite), grey albedo 0.3 … 0.99, g 0 and 0.5, ior 1.4, at two densities each: the least density at
which ``auto`` calls the material opaque (99 % of the light leaves within a pixel of where it
entered, renderer/materials/auto.py) and four times that. For each, the reference is Mitsuba 3
``volpath`` (Lucent's ``volumetric`` without Mitsuba) at ``--ref-spp``; ``auto`` (which must
choose ``opaque``) and ``volumetric`` render a ladder of 16, 64, 256 and ``--spp`` spp. It
records the object pixels' relative MSE against the reference at the top rung, the seconds each
takes to reach the default target (``auto.DEFAULT_TARGET``, read off the ladder as the accuracy
suite does), writes ``opaque.csv`` and ``opaque.md`` to ``--out``, and prints the largest opaque
error: ``auto``'s ``OPAQUE_ERROR``, and the largest at each albedo, its
``OPAQUE_ERROR_BY_ALBEDO`` (tests/renderer/materials/test_opaque.py ties both to the committed
CSV).
"""

from __future__ import annotations

import argparse
import csv
import platform
import time
from pathlib import Path

import numpy as np

from bench.accuracy import _example, object_mask, reference, rel_mse, time_to_target

ROOT = Path(__file__).resolve().parents[1]
ALBEDOS = (0.3, 0.8, 0.95, 0.99)
GS = (0.0, 0.5)
IOR = 1.4
FIELDS = ["albedo", "g", "ior", "density", "reach", "footprint", "auto_method", "spp",
          "opaque_rel_mse", "volumetric_rel_mse", "opaque_seconds", "volumetric_seconds", "target",
          "opaque_s_to_target", "opaque_read", "volumetric_s_to_target", "volumetric_read",
          "reference"]


def scene_for(albedo: float, g: float, density: float, method: str, spp: int) -> dict:
    scene = _example("translucent_sphere")
    scene["materials"]["wax"].update(albedo=[albedo] * 3, g=g, ior=IOR, density=density,
                                     method=method)
    scene["render"].update(spp=spp, seed=7)
    return scene


def least_opaque_density(albedo: float, g: float) -> tuple[float, float]:
    """(density at which the reach equals auto's limit, a pixel's footprint)."""
    from renderer.materials.auto import opaque_limit, opaque_reach, pixel_footprint
    from renderer.scene import load_scene

    scene = load_scene(scene_for(albedo, g, 1.0, "volumetric", 1))
    footprint = pixel_footprint(scene, [o for o in scene.objects if o.material == "wax"])
    limit = opaque_limit(footprint, 0.5)  # the sphere's radius
    # reach scales as 1/density (every length of the model is a multiple of 1/σt')
    return opaque_reach([albedo] * 3, 1.0, g, IOR) / limit, footprint


def timed(scene: dict) -> tuple[float, np.ndarray, dict]:
    from renderer.render import render_buffer
    from renderer.scene import load_scene
    from renderer.scene.compile import compile_scene

    cs = compile_scene(load_scene(scene))
    render_buffer(cs, 1)  # kernels loaded
    start = time.perf_counter()
    buf = render_buffer(cs)
    return time.perf_counter() - start, buf.mean().astype(np.float64), cs.info.get("auto", {})


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spp", type=int, default=1024)
    parser.add_argument("--ref-spp", type=int, default=2048)
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images" / "accuracy")
    args = parser.parse_args(argv)
    from renderer.materials import auto
    from renderer.materials.auto import DEFAULT_TARGET, opaque_reach

    # Measure the regime whatever error auto currently assumes for it: with OPAQUE_ERROR above
    # the default target, auto would not pick the opaque surface at all.
    auto.OPAQUE_ERROR = 0.0
    rows = []
    for g in GS:
        for albedo in ALBEDOS:
            least, footprint = least_opaque_density(albedo, g)
            for factor in (1.0, 4.0):
                density = float(f"{least * factor * 1.001:.4g}")  # just inside the rule
                name = f"dense_sphere_a{albedo}_g{g}_d{density}"
                ref, source = reference(name, scene_for(albedo, g, density, "volumetric", 1),
                                        "wax", args.ref_spp)
                mask = object_mask(scene_for(albedo, g, density, "volumetric", 1), "wax")
                ladder = [n for n in (16, 64, 256) if n < args.spp] + [args.spp]
                curves = {}
                for method in ("auto", "volumetric"):
                    ts, es = [], []
                    for spp in ladder:
                        t, img, chosen_now = timed(scene_for(albedo, g, density, method, spp))
                        ts.append(t)
                        es.append(rel_mse(img, ref, mask))
                        if method == "auto":
                            chosen = chosen_now
                    curves[method] = (np.array(ts), np.array(es))
                (ta, ea), (tv, ev) = curves["auto"], curves["volumetric"]
                ta_hit, ta_how = time_to_target(ta, ea, DEFAULT_TARGET, False)
                tv_hit, tv_how = time_to_target(tv, ev, DEFAULT_TARGET, True)
                t_auto, t_vol = ta[-1], tv[-1]
                row = {"albedo": albedo, "g": g, "ior": IOR, "density": density,
                       "reach": opaque_reach([albedo] * 3, density, g, IOR),
                       "footprint": footprint, "auto_method": chosen["wax"]["method"],
                       "spp": args.spp, "opaque_rel_mse": ea[-1], "volumetric_rel_mse": ev[-1],
                       "opaque_seconds": t_auto, "volumetric_seconds": t_vol,
                       "target": DEFAULT_TARGET, "opaque_s_to_target": ta_hit,
                       "opaque_read": ta_how, "volumetric_s_to_target": tv_hit,
                       "volumetric_read": tv_how, "reference": source.replace(" (cached)", "")}
                rows.append(row)
                print(f"albedo {albedo} g {g} density {density:g}: auto -> {row['auto_method']}, "
                      f"relMSE opaque {row['opaque_rel_mse']:.4g} / volumetric "
                      f"{row['volumetric_rel_mse']:.4g}, {t_auto:.3f} s / {t_vol:.3f} s; to "
                      f"{DEFAULT_TARGET:g}: {ta_hit:.3g} s ({ta_how}) / {tv_hit:.3g} s ({tv_how})",
                      flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "opaque.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, FIELDS)
        writer.writeheader()
        writer.writerows(rows)
    worst = max(r["opaque_rel_mse"] for r in rows)
    lines = [
        f"Written by `python -m bench.opaque --spp {args.spp} --ref-spp {args.ref_spp}` on "
        f"{platform.machine()}, 2 threads. Object pixels' relMSE against the reference at "
        f"{args.spp} spp; seconds to the default target (relMSE {rows[0]['target']:g}) read off "
        "each ladder (≤: already below it at 16 spp, an upper bound; *: extrapolated with slope "
        "−1 beyond the last rung).",
        "",
        "| albedo | g | density | reach / limit | auto | relMSE opaque | relMSE volumetric "
        f"| s to {rows[0]['target']:g}: opaque | volumetric | speed-up |",
        "|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|",
    ]
    mark = {"first point": "≤", "extrapolated": "*", "measured": "", "never": " (never)"}
    for r in rows:
        limit = min(r["footprint"], 0.05)
        lines.append(
            f"| {r['albedo']} | {r['g']} | {r['density']:g} | {r['reach'] / limit:.2f} "
            f"| {r['auto_method']} | {r['opaque_rel_mse']:.4f} | {r['volumetric_rel_mse']:.4f} "
            f"| {r['opaque_s_to_target']:.3g}{mark[r['opaque_read']]} "
            f"| {r['volumetric_s_to_target']:.3g}{mark[r['volumetric_read']]} "
            f"| ×{r['volumetric_s_to_target'] / r['opaque_s_to_target']:.1f} |")
    lines += ["", f"Largest opaque relMSE (auto's OPAQUE_ERROR): {worst:.4g}; references: "
              f"{rows[0]['reference']}.", ""]
    (args.out / "opaque.md").write_text("\n".join(lines))
    print(f"largest opaque relMSE {worst:.4g} -> renderer/materials/auto.py OPAQUE_ERROR")
    by_albedo = {a: max(r["opaque_rel_mse"] for r in rows if r["albedo"] == a) for a in ALBEDOS}
    print("largest at each albedo " + ", ".join(f"{a:g}: {e:.4g}" for a, e in by_albedo.items())
          + " -> OPAQUE_ERROR_BY_ALBEDO")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
