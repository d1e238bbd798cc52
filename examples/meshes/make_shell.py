"""Write examples/meshes/shell.ply, the hollow sphere of examples/translucent_shell.json.

    python examples/meshes/make_shell.py

A thin translucent shell is one closed mesh with two sheets: an outer icosphere whose triangles
face out, and a smaller inner one whose triangles face the cavity. Both renderers decide which side
of a surface the medium is on from the face normal (the medium is behind it), so the material fills
only the wall between the sheets and the cavity is air.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from renderer.geometry.meshio import write_ply

CENTER = (0.0, -0.5, 0.0)
OUTER, INNER = 0.5, 0.46  # wall 0.04 thick
SUBDIVISIONS = 4  # 5120 triangles a sheet


def icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit icosphere (Loop-style midpoint subdivision of the icosahedron), faces counter-clockwise
    seen from outside."""
    p = (1 + 5**0.5) / 2
    verts = [(-1, p, 0), (1, p, 0), (-1, -p, 0), (1, -p, 0), (0, -1, p), (0, 1, p),
             (0, -1, -p), (0, 1, -p), (p, 0, -1), (p, 0, 1), (-p, 0, -1), (-p, 0, 1)]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
             (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
             (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    verts = [np.array(v, float) / np.linalg.norm(v) for v in verts]
    for _ in range(subdivisions):
        midpoint: dict[tuple[int, int], int] = {}

        def mid(i: int, j: int) -> int:
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


def shell(outer: float, inner: float, subdivisions: int, center=CENTER):
    v, t = icosphere(subdivisions)
    verts = np.concatenate([v * outer, v * inner]) + np.asarray(center)
    # The inner sheet's triangles are reversed so that its normals point into the cavity
    tris = np.concatenate([t, t[:, ::-1] + len(v)])
    return verts, tris


if __name__ == "__main__":
    v, t = shell(OUTER, INNER, SUBDIVISIONS)
    out = Path(__file__).with_name("shell.ply")
    write_ply(out, v, t, vertex_type="float")
    print(f"wrote {out}: {len(v)} vertices, {len(t)} triangles")
