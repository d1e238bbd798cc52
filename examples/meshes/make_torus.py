"""Write examples/meshes/torus.ply, the closed triangle mesh of examples/mesh_torus.json.

    python examples/meshes/make_torus.py
"""

from __future__ import annotations

from pathlib import Path

from renderer.geometry.meshgen import torus
from renderer.geometry.meshio import write_ply

if __name__ == "__main__":
    v, t = torus(0.6, 0.25, 96, 48)
    out = Path(__file__).with_name("torus.ply")
    write_ply(out, v, t)
    print(f"wrote {out}: {len(v)} vertices, {len(t)} triangles")
