"""Render the pictures and measurements of docs/methods/ (run from the repository root).

    .venv/bin/python docs/methods/make_images.py compare   # 5 methods × 2 scenes, ~10 s each
    .venv/bin/python docs/methods/make_images.py bias      # each method against Mitsuba volpath
    .venv/bin/python docs/methods/make_images.py cost      # cost on a lone sphere; direct_light
    .venv/bin/python docs/methods/make_images.py seeds     # the seed-reproduction examples

Scene copies with ``material.method`` switched are written under /tmp; the examples themselves are
never changed. Timings are wall-clock seconds of ``render_buffer`` after a 1-spp warm-up (numba
compiled), on whatever machine runs this; measurements.json records them with the machine's CPU
count.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from renderer.film.image_io import write_image  # noqa: E402
from renderer.render import render_buffer  # noqa: E402
from renderer.scene import load_scene  # noqa: E402

OUT = ROOT / "docs" / "images" / "methods"
TMP = Path("/tmp/lucent_methods")
METHODS = ["volumetric", "single_scatter", "diffuse_entry", "backlight", "diffusion"]
SCENES = {"translucent_sphere": "wax", "backlit_slab": "jade"}
SEEDS = ["seed_paper_boxes_low_density", "seed_paper_boxes_high_density", "gummy_backlit",
         "candle_forward", "candle_backward"]
BUDGET_S = 10.0
FONT = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf"


def scene_with(name: str, method: str) -> dict:
    data = json.loads((ROOT / "examples" / f"{name}.json").read_text())
    data["materials"][SCENES[name]]["method"] = method
    TMP.mkdir(exist_ok=True)
    (TMP / f"{name}_{method}.json").write_text(json.dumps(data))
    return data


def timed(scene, spp: int):
    render_buffer(scene, 1)  # warm-up: numba's cache loaded, compiled if needed
    start = time.perf_counter()
    buf = render_buffer(scene, spp)
    return buf, time.perf_counter() - start


def load_measurements() -> dict:
    path = OUT / "measurements.json"
    return json.loads(path.read_text()) if path.exists() else {}


def save_measurements(m: dict) -> None:
    m["cpus"] = os.cpu_count()
    (OUT / "measurements.json").write_text(json.dumps(m, indent=1) + "\n")


def grid(name: str, panels: list[tuple[Path, str]], columns: int = 5) -> None:
    """Panels side by side, each with its label on a bar underneath."""
    images = [Image.open(p).convert("RGB") for p, _ in panels]
    w, h = images[0].size
    bar = 22
    rows = (len(images) + columns - 1) // columns
    sheet = Image.new("RGB", (columns * w, rows * (h + bar)), (24, 24, 24))
    draw = ImageDraw.Draw(sheet)
    font = ImageFont.truetype(FONT, 13)
    for i, (img, (_, label)) in enumerate(zip(images, panels, strict=True)):
        x, y = (i % columns) * w, (i // columns) * (h + bar)
        sheet.paste(img, (x, y))
        draw.text((x + 6, y + h + 3), label, fill=(235, 235, 235), font=font)
    sheet.save(OUT / f"{name}_grid.png")


def compare() -> None:
    """Each method on both scenes at ~BUDGET_S seconds: spp from a timed 8-spp calibration."""
    m = load_measurements()
    for name in SCENES:
        panels = []
        for method in METHODS:
            scene = load_scene(scene_with(name, method))
            _, t8 = timed(scene, 8)
            spp = max(1, round(BUDGET_S * 8 / t8))
            buf, seconds = timed(scene, spp)
            path = OUT / f"{name}_{method}.png"
            write_image(path, buf.mean())
            m.setdefault("compare", {}).setdefault(name, {})[method] = {
                "spp": spp, "seconds": round(seconds, 2), "dropped": int(buf.total_dropped)}
            print(name, method, spp, f"{seconds:.1f} s", flush=True)
            panels.append((path, f"{method}  {spp} spp  {seconds:.1f} s"))
        grid(name, panels)
    save_measurements(m)


def object_mask(data: dict, material: str) -> np.ndarray:
    """Pixels that see the object: it alone emits, everything is black, camera rays only."""
    d = json.loads(json.dumps(data))
    d["materials"] = {"black": {"type": "diffuse", "albedo": [0, 0, 0]}}
    for obj in d["objects"]:
        obj["emission"] = [1, 1, 1] if obj["material"] == material else None
        obj["material"] = "black"
    d["lights"] = []
    d["render"].update(max_depth=0)
    return render_buffer(load_scene(d), 16).mean()[..., 0] > 0.99


def bias(spp: int = 1024) -> None:
    """Each method at 64×48 against Mitsuba 3's 16384-spp volpath reference (tests/data)."""
    m = load_measurements()
    lum = np.array([0.2126, 0.7152, 0.0722])
    for name, material in SCENES.items():
        ref = np.load(ROOT / "tests" / "data" / f"{name}_ref.npy").astype(np.float64)
        for method in METHODS:
            data = scene_with(name, method)
            data["film"] = {"width": 64, "height": 48}
            if method == METHODS[0]:
                mask = object_mask(data, material)
            img = render_buffer(load_scene(data), spp).mean().astype(np.float64)
            obj_ratio = (img[mask] @ lum).mean() / (ref[mask] @ lum).mean()
            frame_ratio = (img @ lum).mean() / (ref @ lum).mean()
            rel_rmse = np.sqrt(np.mean((img[mask] - ref[mask]) ** 2)) / ref[mask].mean()
            m.setdefault("bias", {}).setdefault(name, {})[method] = {
                "spp": spp, "object_luminance_ratio": round(float(obj_ratio), 4),
                "frame_luminance_ratio": round(float(frame_ratio), 4),
                "object_relative_rmse": round(float(rel_rmse), 4),
                "object_pixels": int(mask.sum())}
            print(name, method, m["bias"][name][method], flush=True)
    save_measurements(m)


def cost(spp: int = 32) -> None:
    """Seconds per frame of each method on a sphere filling a 64×48 view under a uniform
    background (nothing else in the scene), albedo 0.99, g 0.3, ior 1.4, at densities 8 and 100:
    the random walk's length grows with the number of mean free paths, the others' does not."""
    m = load_measurements()
    for density in (8.0, 100.0):
        for method in METHODS:
            data = {
                "camera": {"position": [0, 0, 3.2], "look_at": [0, 0, 0], "fov": 40},
                "film": {"width": 64, "height": 48},
                "render": {"spp": spp, "max_depth": -1, "seed": 1},
                "background": [1, 1, 1],
                "materials": {"m": {"type": "translucent", "method": method, "ior": 1.4,
                                    "albedo": [0.99, 0.99, 0.99], "density": density, "g": 0.3}},
                "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1.0,
                             "material": "m"}],
            }
            buf, seconds = timed(load_scene(data), spp)
            m.setdefault("cost", {}).setdefault(f"density {density:g}", {})[method] = {
                "spp": spp, "seconds": round(seconds, 3),
                "mean": round(float(buf.mean()[12:36, 20:44].mean()), 4)}
            print(density, method, m["cost"][f"density {density:g}"][method], flush=True)
    # diffuse_entry's separate direct light against its own full path tracing, and the reference
    ref = np.load(ROOT / "tests" / "data" / "translucent_sphere_ref.npy").astype(np.float64)
    data = scene_with("translucent_sphere", "diffuse_entry")
    data["film"] = {"width": 64, "height": 48}
    mask = object_mask(data, "wax")
    lum = np.array([0.2126, 0.7152, 0.0722])
    for direct in (False, True):
        data["materials"]["wax"]["direct_light"] = direct
        img = render_buffer(load_scene(data), 1024).mean().astype(np.float64)
        ratio = (img[mask] @ lum).mean() / (ref[mask] @ lum).mean()
        m.setdefault("direct_light", {})[str(direct).lower()] = round(float(ratio), 4)
        print("direct_light", direct, ratio, flush=True)
    save_measurements(m)


def seeds() -> None:
    m = load_measurements()
    for name in SEEDS:
        if os.environ.get("ONLY") and name not in os.environ["ONLY"].split(","):
            continue
        scene = load_scene(json.loads((ROOT / "examples" / f"{name}.json").read_text()))
        buf, seconds = timed(scene, scene.render.spp)
        write_image(OUT / f"{name}.png", buf.mean())
        m.setdefault("seeds", {})[name] = {"spp": scene.render.spp, "seconds": round(seconds, 2),
                                           "dropped": int(buf.total_dropped)}
        print(name, scene.render.spp, f"{seconds:.1f} s", flush=True)
    save_measurements(m)


if __name__ == "__main__":
    OUT.mkdir(parents=True, exist_ok=True)
    for stage in sys.argv[1:] or ["compare", "bias", "cost", "seeds"]:
        {"compare": compare, "bias": bias, "cost": cost, "seeds": seeds}[stage]()
