"""The Mitsuba bridge on the chart suite's new shapes: mesh files relative to the scene, and a
hollow mesh (examples/meshes/make_shell.py) whose medium fills only the wall between its sheets.

The shell test is a closed form: with an index-matched boundary (ior 1) and albedo 0 the medium
only absorbs, so a ray through the shell keeps exp(−σ·ℓ) of a constant background, ℓ being the
length of the ray inside the wall (Beer–Lambert). ℓ is computed here by intersecting the camera's
rays with the same triangles in NumPy. Were the medium on the wrong side of either sheet (a
filled sphere, or a filled cavity), the image mean would be exp(−σ·chord) instead: 0.02 against
0.34 here.
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

mi = pytest.importorskip("mitsuba")

from renderer.geometry.meshio import write_ply  # noqa: E402
from renderer.mitsuba_bridge import (  # noqa: E402  (after the importorskip on purpose)
    default_variant,
    render_mitsuba,
    to_mitsuba_dict,
)

pytestmark = pytest.mark.mitsuba

MESHES = Path(__file__).resolve().parents[2] / "examples" / "meshes"
VARIANT = default_variant()


def _make_shell():
    spec = importlib.util.spec_from_file_location("make_shell", MESHES / "make_shell.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _scene(mesh: dict, density: float, fov: float, size: int) -> dict:
    return {
        "camera": {"position": [0, 0, 3], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": fov},
        "film": {"width": size, "height": size},
        "render": {"spp": 4, "max_depth": -1, "seed": 0},
        "background": [1.0, 1.0, 1.0],
        "materials": {"ink": {"type": "translucent", "method": "volumetric", "ior": 1.0,
                              "albedo": [0.0, 0.0, 0.0], "density": density, "g": 0.0}},
        "objects": [dict(mesh, material="ink")],
    }


def _lengths_inside(origin, dirs, verts, tris):
    """Σ over hits of ±t (Möller–Trumbore): entering a face (d·n < 0) subtracts its distance,
    leaving adds it, so the sum is the length inside a closed, consistently oriented mesh."""
    v0, v1, v2 = verts[tris[:, 0]], verts[tris[:, 1]], verts[tris[:, 2]]
    e1, e2 = v1 - v0, v2 - v0
    n = np.cross(e1, e2)
    out = np.zeros(len(dirs))
    for k, d in enumerate(dirs):
        p = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, p)
        s = origin - v0
        u = np.einsum("ij,ij->i", s, p) / det
        q = np.cross(s, e1)
        v = (q @ d) / det
        t = np.einsum("ij,ij->i", e2, q) / det
        hit = (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        out[k] = np.sum(np.where(n[hit] @ d < 0, -t[hit], t[hit]))
    return out


def test_a_hollow_mesh_absorbs_only_in_its_wall():
    shell = _make_shell()
    verts, tris = shell.shell(0.5, 0.4, 2, center=(0.0, 0.0, 0.0))
    density, fov, size, spp = 5.0, 6.0, 8, 512
    mesh = {"type": "mesh", "vertices": verts.tolist(), "triangles": tris.tolist()}
    img = render_mitsuba(_scene(mesh, density, fov, size), spp=spp, seed=3, variant=VARIANT)

    # The same pixel footprint (box filter: uniform over the image plane), 4096 rays
    rng = np.random.default_rng(0)
    half = math.tan(math.radians(fov) / 2)
    xy = rng.uniform(-half, half, (4096, 2))
    dirs = np.column_stack([xy, -np.ones(len(xy))])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    ell = _lengths_inside(np.array([0.0, 0.0, 3.0]), dirs, verts, tris)
    assert 0.19 < ell.min() and ell.max() < 0.25  # two walls of 0.1, faceted, a little oblique
    expected = np.exp(-density * ell).mean()
    # Each sample is 0 or 1 (albedo 0: absorbed or not), so the image mean has a standard error
    # of sqrt(T(1 − T)/N), N = 8·8·512 = 32768: 0.0026 at T = 0.37. 5 SE, plus 0.002 for the
    # 4096-ray estimate of the expectation (its SD is < 0.0005).
    se = math.sqrt(expected * (1 - expected) / (size * size * spp))
    assert abs(img.mean() - expected) < 5 * se + 0.002, (img.mean(), expected)


def test_mesh_paths_are_read_relative_to_base_dir(tmp_path):
    verts, tris = _make_shell().shell(0.5, 0.4, 1, center=(0.0, 0.0, 0.0))
    write_ply(tmp_path / "shell.ply", verts, tris)
    scene = _scene({"type": "mesh", "path": "shell.ply"}, 5.0, 6.0, 8)
    d = to_mitsuba_dict(scene, variant=VARIANT, base_dir=tmp_path)
    # read by Lucent's reader from base_dir and given to Mitsuba inline
    assert d["object_000"].face_count() == len(tris)
    with pytest.raises(ValueError, match="shell.ply"):
        to_mitsuba_dict(scene, variant=VARIANT, base_dir=tmp_path / "elsewhere")
    inline = {"type": "mesh", "vertices": verts.tolist(), "triangles": tris.tolist()}
    a = render_mitsuba(scene, spp=64, seed=1, variant=VARIANT, base_dir=tmp_path)
    b = render_mitsuba(_scene(inline, 5.0, 6.0, 8), spp=64, seed=1, variant=VARIANT)
    # The same triangles and the same seed: the same image up to float32 vertex rounding
    np.testing.assert_allclose(a.mean(), b.mean(), rtol=0.02)
