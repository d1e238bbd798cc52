"""Write the seed-reproduction examples of docs/methods/ (run from the repository root).

    .venv/bin/python docs/methods/make_examples.py

examples/seed_paper_boxes_{low,high}_density.json, examples/gummy_backlit.json and
examples/candle_{forward,backward}.json. The meshes (ellipsoids, a cylinder) are generated here and
written inline, so every example is a plain scene file. Check them with ``lucent validate``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def r(x: float) -> float:
    return round(x, 5) + 0.0


def ellipsoid(center, radii, n_lon=20, n_lat=12) -> dict:
    """A closed UV ellipsoid: two pole vertices and n_lat − 1 rings; counter-clockwise outside."""
    cx, cy, cz = center
    ax, ay, az = radii
    verts = [[cx, cy + ay, cz]]
    for i in range(1, n_lat):
        theta = math.pi * i / n_lat
        for j in range(n_lon):
            phi = 2 * math.pi * j / n_lon
            verts.append([r(cx + ax * math.sin(theta) * math.cos(phi)),
                          r(cy + ay * math.cos(theta)),
                          r(cz - az * math.sin(theta) * math.sin(phi))])
    verts.append([cx, cy - ay, cz])
    bottom = len(verts) - 1

    def ring(i, j):
        return 1 + (i - 1) * n_lon + j % n_lon

    tris = []
    for j in range(n_lon):
        tris.append([0, ring(1, j), ring(1, j + 1)])
        tris.append([bottom, ring(n_lat - 1, j + 1), ring(n_lat - 1, j)])
    for i in range(1, n_lat - 1):
        for j in range(n_lon):
            a, b = ring(i, j), ring(i, j + 1)
            c, d = ring(i + 1, j), ring(i + 1, j + 1)
            tris.append([a, c, d])
            tris.append([a, d, b])
    return {"type": "mesh", "vertices": verts, "triangles": tris}


def cylinder(base, radius, height, n=32) -> dict:
    """A closed cylinder standing on ``base`` (its axis along +y), with both caps."""
    bx, by, bz = base
    verts = []
    for y in (by, by + height):
        for j in range(n):
            phi = 2 * math.pi * j / n
            verts.append([r(bx + radius * math.cos(phi)), r(y), r(bz - radius * math.sin(phi))])
    bottom, top = 2 * n, 2 * n + 1
    verts += [[bx, by, bz], [bx, by + height, bz]]
    tris = []
    for j in range(n):
        k = (j + 1) % n
        tris.append([j, k, n + k])
        tris.append([j, n + k, n + j])
        tris.append([bottom, k, j])
        tris.append([top, n + j, n + k])
    return {"type": "mesh", "vertices": verts, "triangles": tris}


def room(half=1.0) -> list[dict]:
    """Floor, ceiling, back wall, red left and green right walls of a Cornell-style room."""
    h = half
    return [
        {"type": "quad", "origin": [-h, -h, h], "edge1": [2 * h, 0, 0], "edge2": [0, 0, -2 * h],
         "material": "white"},
        {"type": "quad", "origin": [-h, h, -h], "edge1": [2 * h, 0, 0], "edge2": [0, 0, 2 * h],
         "material": "white"},
        {"type": "quad", "origin": [-h, -h, -h], "edge1": [2 * h, 0, 0], "edge2": [0, 2 * h, 0],
         "material": "white"},
        {"type": "quad", "origin": [-h, -h, h], "edge1": [0, 0, -2 * h], "edge2": [0, 2 * h, 0],
         "material": "red"},
        {"type": "quad", "origin": [h, -h, -h], "edge1": [0, 0, 2 * h], "edge2": [0, 2 * h, 0],
         "material": "green"},
    ]


ROOM_MATERIALS = {
    "white": {"type": "diffuse", "albedo": [0.73, 0.73, 0.73]},
    "red": {"type": "diffuse", "albedo": [0.63, 0.065, 0.05]},
    "green": {"type": "diffuse", "albedo": [0.14, 0.45, 0.091]},
    "light": {"type": "diffuse", "albedo": [0.78, 0.78, 0.78]},
}


def seed_paper_boxes(density: float) -> dict:
    """The seed paper's figures 2 and 3: two translucent boxes (single_scatter) in a room lit by a
    ceiling light. The paper gives no densities, sizes or colours, and says its 80 % surface share
    "can be adjusted": at 0.8 the Lambertian surface hides the volume, so these use 0.5. The boxes
    are 0.6 wide: density 1 is ~0.6 mean free paths across, density 30 is ~18."""
    box = {"type": "translucent", "method": "single_scatter", "ior": 1.0, "density": density,
           "g": 0.0, "surface_fraction": 0.5}
    return {
        "camera": {"position": [0, 0, 3.9], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 39.0},
        "film": {"width": 320, "height": 240},
        "render": {"spp": 128, "max_depth": 8, "seed": 1},
        "materials": ROOM_MATERIALS | {
            "blue_box": box | {"albedo": [0.55, 0.75, 0.95]},
            "amber_box": box | {"albedo": [0.95, 0.75, 0.4]},
        },
        "objects": room() + [
            {"type": "box", "min": [-0.3, -1.0, -0.3], "max": [0.3, 0.2, 0.3],
             "rotate": {"axis": [0, 1, 0], "angle": 18}, "translate": [-0.35, 0, -0.3],
             "material": "blue_box"},
            {"type": "box", "min": [-0.3, -1.0, -0.3], "max": [0.3, -0.4, 0.3],
             "rotate": {"axis": [0, 1, 0], "angle": -17}, "translate": [0.38, 0, 0.3],
             "material": "amber_box"},
            {"type": "quad", "origin": [-0.25, 0.99, -0.25], "edge1": [0.5, 0, 0],
             "edge2": [0, 0, 0.5], "material": "light", "emission": [17, 12, 4]},
        ],
    }


def gummy_backlit() -> dict:
    """A gummy bear of separate ellipsoids (non-overlapping: each piece is its own closed medium),
    method backlight, with a panel light hidden behind it, a fill light from the front right and a
    grey back wall."""
    m = "gummy"

    def part(center, radii, n_lon=20, n_lat=12):
        return ellipsoid(center, radii, n_lon, n_lat) | {"material": m}

    bear = [
        part([0, -0.2, 0], [0.42, 0.5, 0.3]),  # body
        part([0, 0.6, 0], [0.34, 0.28, 0.26]),  # head
        part([-0.26, 0.94, 0], [0.11, 0.1, 0.08], 12, 8),  # ears
        part([0.26, 0.94, 0], [0.11, 0.1, 0.08], 12, 8),
        part([-0.55, 0.02, 0.05], [0.13, 0.2, 0.13], 12, 8),  # arms
        part([0.55, 0.02, 0.05], [0.13, 0.2, 0.13], 12, 8),
        part([-0.24, -0.84, 0.06], [0.17, 0.13, 0.17], 12, 8),  # legs
        part([0.24, -0.84, 0.06], [0.17, 0.13, 0.17], 12, 8),
    ]
    return {
        "camera": {"position": [0, 0.05, 3.6], "look_at": [0, 0, 0], "up": [0, 1, 0],
                   "fov": 40.0},
        "film": {"width": 320, "height": 240},
        "render": {"spp": 64, "max_depth": 6, "seed": 1},
        "background": [0.02, 0.02, 0.03],
        "materials": {
            m: {"type": "translucent", "method": "backlight", "ior": 1.45,
                "albedo": [0.98, 0.3, 0.08], "density": 6.0, "g": 0.2,
                "distortion": 0.2, "power": 4.0, "scale": 0.7},
            "floor": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]},
            "lamp": {"type": "diffuse", "albedo": [0, 0, 0]},
        },
        "objects": bear + [
            {"type": "quad", "origin": [-5, -0.98, 5], "edge1": [10, 0, 0], "edge2": [0, 0, -10],
             "material": "floor"},
            {"type": "quad", "origin": [-0.3, -0.55, -1.0], "edge1": [0.6, 0, 0],
             "edge2": [0, 0.7, 0], "material": "lamp", "emission": [24, 22, 19]},
            {"type": "quad", "origin": [-5, -0.98, -3], "edge1": [10, 0, 0], "edge2": [0, 6, 0],
             "material": "floor"},
        ],
        "lights": [{"type": "point", "position": [2.0, 2.0, 3.0], "intensity": [2.5, 2.5, 2.5]}],
    }


def candle(g: float) -> dict:
    """The seed student project's candle: a wax cylinder (diffuse_entry) and a small warm flame
    just above it, with g = +0.7 (forward) or −0.7 (backward), and a faint blue fill."""
    return {
        "camera": {"position": [0, 0.55, 3.0], "look_at": [0, 0.1, 0], "up": [0, 1, 0],
                   "fov": 36.0},
        "film": {"width": 320, "height": 240},
        "render": {"spp": 192, "max_depth": 16, "seed": 1},
        "background": [0.01, 0.012, 0.02],
        "materials": {
            "wax": {"type": "translucent", "method": "diffuse_entry", "ior": 1.4,
                    "albedo": [0.97, 0.93, 0.85], "density": 12.0, "g": g},
            "floor": {"type": "diffuse", "albedo": [0.35, 0.3, 0.25]},
            "flame": {"type": "diffuse", "albedo": [0, 0, 0]},
        },
        "objects": [
            cylinder([0, -0.6, 0], 0.22, 1.1) | {"material": "wax"},
            {"type": "sphere", "center": [0, 0.64, 0], "radius": 0.09, "material": "flame",
             "emission": [30, 14, 4]},
            {"type": "quad", "origin": [-4, -0.6, 4], "edge1": [8, 0, 0], "edge2": [0, 0, -8],
             "material": "floor"},
        ],
    }


def dump(scene: dict) -> str:
    """One top-level key a line, one material or object a line (as the other examples)."""
    lines = ["{"]
    keys = list(scene)
    for i, key in enumerate(keys):
        comma = "," if i < len(keys) - 1 else ""
        value = scene[key]
        if key == "materials":
            inner = [f"    {json.dumps(k)}: {json.dumps(v)}" for k, v in value.items()]
            lines.append('  "materials": {\n' + ",\n".join(inner) + f"\n  }}{comma}")
        elif key in ("objects", "lights"):
            inner = [f"    {json.dumps(v)}" for v in value]
            lines.append(f'  "{key}": [\n' + ",\n".join(inner) + f"\n  ]{comma}")
        else:
            lines.append(f"  {json.dumps(key)}: {json.dumps(value)}{comma}")
    return "\n".join(lines) + "\n}\n"


if __name__ == "__main__":
    out = {
        "seed_paper_boxes_low_density": seed_paper_boxes(1.0),
        "seed_paper_boxes_high_density": seed_paper_boxes(30.0),
        "gummy_backlit": gummy_backlit(),
        "candle_forward": candle(0.7),
        "candle_backward": candle(-0.7),
    }
    for name, scene in out.items():
        (ROOT / "examples" / f"{name}.json").write_text(dump(scene))
        print("wrote", f"examples/{name}.json")
