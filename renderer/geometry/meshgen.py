"""Meshes made by formula, for the examples, the benchmarks and the tests."""

from __future__ import annotations

import numpy as np


def torus(major: float, minor: float, n_major: int, n_minor: int,
          axis: str = "y") -> tuple[np.ndarray, np.ndarray]:
    """A closed torus about the ``axis`` ("y" or "z") through the origin: ``n_major`` × ``n_minor``
    vertices on the tube's rings and 2·n_major·n_minor triangles, counter-clockwise seen from
    outside (normals out). Returns (vertices (n, 3) float64, triangles (m, 3) int)."""
    if axis not in ("y", "z"):
        raise ValueError(f"axis must be 'y' or 'z', not {axis!r}")
    u = np.linspace(0, 2 * np.pi, n_major, endpoint=False)
    v = np.linspace(0, 2 * np.pi, n_minor, endpoint=False)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    r = major + minor * np.cos(vv)
    i, j = np.meshgrid(np.arange(n_major), np.arange(n_minor), indexing="ij")
    a = i * n_minor + j
    b = ((i + 1) % n_major) * n_minor + j
    c = ((i + 1) % n_major) * n_minor + (j + 1) % n_minor
    d = i * n_minor + (j + 1) % n_minor
    if axis == "y":
        verts = np.stack([r * np.cos(uu), minor * np.sin(vv), r * np.sin(uu)], -1)
        tris = np.concatenate([np.stack([a, d, c], -1), np.stack([a, c, b], -1)])
    else:
        # The y torus with y and z swapped, a reflection: the winding turns to stay outward
        verts = np.stack([r * np.cos(uu), r * np.sin(uu), minor * np.sin(vv)], -1)
        tris = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)])
    return verts.reshape(-1, 3), tris.reshape(-1, 3)
