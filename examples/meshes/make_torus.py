"""Write examples/meshes/torus.ply, the closed triangle mesh of examples/mesh_torus.json.

    python examples/meshes/make_torus.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from renderer.geometry.meshio import write_ply


def torus(major: float, minor: float, n_major: int, n_minor: int):
    """A closed torus about the y axis, triangles counter-clockwise seen from outside."""
    u = np.linspace(0, 2 * np.pi, n_major, endpoint=False)
    v = np.linspace(0, 2 * np.pi, n_minor, endpoint=False)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    r = major + minor * np.cos(vv)
    verts = np.stack([r * np.cos(uu), minor * np.sin(vv), r * np.sin(uu)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_major), np.arange(n_minor), indexing="ij")
    a = i * n_minor + j
    b = ((i + 1) % n_major) * n_minor + j
    c = ((i + 1) % n_major) * n_minor + (j + 1) % n_minor
    d = i * n_minor + (j + 1) % n_minor
    tris = np.concatenate([np.stack([a, d, c], -1), np.stack([a, c, b], -1)]).reshape(-1, 3)
    return verts, tris


if __name__ == "__main__":
    v, t = torus(0.6, 0.25, 96, 48)
    out = Path(__file__).with_name("torus.ply")
    write_ply(out, v, t)
    print(f"wrote {out}: {len(v)} vertices, {len(t)} triangles")
