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


def sheet(n: int, z: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """An open n × n sheet of quads over [0, 1]² at height ``z``: (n + 1)² vertices, row by row
    (vertex j·(n + 1) + i at (i/n, j/n, z)), and 2n² triangles facing +z. Large inline meshes for
    the submission limits and their benchmark. Returns (vertices float64, triangles int64)."""
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1))
    vertices = np.stack([i.ravel() / n, j.ravel() / n, np.full(i.size, z)], axis=1)
    a = (np.arange(n)[None, :] + (n + 1) * np.arange(n)[:, None]).ravel()
    triangles = np.stack([np.stack([a, a + 1, a + n + 2], axis=1),
                          np.stack([a, a + n + 2, a + n + 1], axis=1)], axis=1).reshape(-1, 3)
    return vertices, triangles.astype(np.int64)


def uv_sphere(n_lon: int, n_lat: int, radius: float = 1.0
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A closed sphere of ``n_lon`` × ``n_lat`` quads (fans at the poles), counter-clockwise seen
    from outside. Returns (vertices, triangles, normals (the unit radial directions: smooth
    shading), uvs in the sphere's parametrization of the scene format, u = atan2(x, −z)/(2π),
    v = 1 − acos(y)/π). The seam's vertices are doubled (u runs 0 to 1 across it) and the poles'
    repeated per column: geometrically closed, but not an edge-manifold, so not for the materials
    that need an inside (dielectric, translucent)."""
    u = np.arange(n_lon + 1) / n_lon
    v = np.arange(n_lat + 1) / n_lat
    uu, vv = np.meshgrid(u, v, indexing="ij")  # vertex (i, j): i along u, j along v
    theta = np.pi * (1.0 - vv)  # from +y
    phi = 2.0 * np.pi * uu
    normals = np.stack([np.sin(theta) * np.sin(phi), np.cos(theta),
                        -np.sin(theta) * np.cos(phi)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_lon), np.arange(n_lat), indexing="ij")
    a = i * (n_lat + 1) + j
    b = (i + 1) * (n_lat + 1) + j
    c, d = b + 1, a + 1
    # Seen from outside, u grows to the left (westwards, like a globe's inside-out map) and v
    # upwards: (a, c, b) turns counter-clockwise
    lower = np.stack([a, c, b], -1)[:, 1:]  # the bottom row's (a, b) is the pole: one triangle
    upper = np.stack([a, d, c], -1)[:, :-1]
    triangles = np.concatenate([lower.reshape(-1, 3), upper.reshape(-1, 3)])
    uvs = np.stack([uu, vv], -1).reshape(-1, 2)
    return radius * normals, triangles.astype(np.int64), normals, uvs


def icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit icosphere (midpoint subdivision of the icosahedron, welded: a closed edge-manifold),
    faces counter-clockwise seen from outside; its vertices are its smooth normals."""
    p = (1 + 5**0.5) / 2
    verts = [(-1, p, 0), (1, p, 0), (-1, -p, 0), (1, -p, 0), (0, -1, p), (0, 1, p),
             (0, -1, -p), (0, 1, -p), (p, 0, -1), (p, 0, 1), (-p, 0, -1), (-p, 0, 1)]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
             (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
             (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    verts = [np.array(v, float) / np.linalg.norm(v) for v in verts]
    for _ in range(subdivisions):
        midpoint: dict[tuple[int, int], int] = {}

        def mid(i: int, j: int, midpoint: dict[tuple[int, int], int] = midpoint) -> int:
            key = (min(i, j), max(i, j))
            if key not in midpoint:
                m = verts[i] + verts[j]
                verts.append(m / np.linalg.norm(m))
                midpoint[key] = len(verts) - 1
            return midpoint[key]

        new = []
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new
    return np.array(verts), np.array(faces, np.int64)
