"""Meshes made by formula (renderer/geometry/meshgen.py): closed, oriented outward, of the right
size."""

from __future__ import annotations

import math

import numpy as np
import pytest

from renderer.geometry.meshgen import sheet, torus
from renderer.scene.load import find_open_edge


def signed_volume(vertices: np.ndarray, triangles: np.ndarray) -> float:
    """The divergence theorem over the triangles: positive when they wind counter-clockwise seen
    from outside."""
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


@pytest.mark.parametrize("axis", ["y", "z"])
def test_torus_is_closed_outward_and_of_the_torus_volume(axis):
    major, minor = 0.6, 0.25
    vertices, triangles = torus(major, minor, 96, 48, axis=axis)
    assert vertices.shape == (96 * 48, 3) and triangles.shape == (2 * 96 * 48, 3)
    assert find_open_edge(triangles) is None
    # 2π²Rr² for the smooth torus; the inscribed polygons are a little smaller (by ~0.3 % here)
    exact = 2 * math.pi**2 * major * minor**2
    assert exact * 0.99 < signed_volume(vertices, triangles) < exact
    # Its symmetry axis: the extent along it is the tube's diameter
    extent = vertices.max(axis=0) - vertices.min(axis=0)
    assert extent["xyz".index(axis)] == pytest.approx(2 * minor, rel=1e-3)


def test_torus_refuses_another_axis():
    with pytest.raises(ValueError, match="axis"):
        torus(1.0, 0.3, 8, 4, axis="x")


def test_sheet_lays_its_vertices_row_by_row_and_faces_up():
    v, t = sheet(3, z=0.25)
    assert v.shape == (16, 3) and t.shape == (18, 3) and t.dtype == np.int64
    np.testing.assert_array_equal(v[1 * 4 + 2], [2 / 3, 1 / 3, 0.25])  # vertex j·(n + 1) + i
    e1, e2 = v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]
    normals = np.cross(e1, e2)
    assert np.all(normals[:, 2] > 0) and np.allclose(normals[:, :2], 0)
    assert np.isclose(0.5 * normals[:, 2].sum(), 1.0)  # the triangles tile the unit square


def test_uv_sphere_faces_out_and_carries_the_sphere_parametrization():
    from renderer.geometry.meshgen import uv_sphere

    vertices, triangles, normals, uvs = uv_sphere(16, 10, radius=2.0)
    e1 = vertices[triangles[:, 1]] - vertices[triangles[:, 0]]
    e2 = vertices[triangles[:, 2]] - vertices[triangles[:, 0]]
    centres = vertices[triangles].mean(axis=1)
    assert (np.einsum("ij,ij->i", np.cross(e1, e2), centres) > 0).all()  # outward
    np.testing.assert_allclose(np.linalg.norm(vertices, axis=1), 2.0)
    np.testing.assert_allclose(normals, vertices / 2.0, atol=1e-15)
    # u = atan2(x, −z)/(2π) mod 1, v = 1 − acos(y)/π away from the seam and the poles
    inner = (uvs[:, 0] > 0) & (uvs[:, 0] < 1) & (uvs[:, 1] > 0) & (uvs[:, 1] < 1)
    d = normals[inner]
    np.testing.assert_allclose(uvs[inner, 0], np.mod(np.arctan2(d[:, 0], -d[:, 2]) / (2 * np.pi),
                                                     1.0), atol=1e-12)
    np.testing.assert_allclose(uvs[inner, 1], 1.0 - np.arccos(d[:, 1]) / np.pi, atol=1e-12)
