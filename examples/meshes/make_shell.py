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

from renderer.geometry.meshgen import icosphere
from renderer.geometry.meshio import write_ply

CENTER = (0.0, -0.5, 0.0)
OUTER, INNER = 0.5, 0.46  # wall 0.04 thick
SUBDIVISIONS = 4  # 5120 triangles a sheet


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
