"""Texture coordinates and shading normals of meshes: OBJ ``vt``/``vn`` (split at seams), PLY
``u,v``/``s,t`` and ``nx,ny,nz``, inline ``uvs``/``normals`` and their errors, placement of
normals, and their interpolation across a triangle (scene format v1.1)."""

from __future__ import annotations

import numpy as np
import pytest

from renderer.geometry.meshgen import uv_sphere
from renderer.geometry.meshio import _obj_corners_bulk, _parse_obj_corners, parse_mesh
from renderer.geometry.shapes import QUAD, TRIANGLE, interpolated_normal
from renderer.scene import SceneError, load_scene

# Two triangles sharing the edge 0-2, the shared corners with different vt on each side (a seam)
SEAM_OBJ = b"""\
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vt 0.5 0.5
vn 0 0 1
vn 0 0.6 0.8
f 1/1/1 2/2/1 3/3/2
f 1/5/1 3/3/2 4/4/1
"""


def test_obj_corners_split_at_seams():
    vertices, triangles, uvs, normals = parse_mesh(SEAM_OBJ, ".obj", name="seam.obj")
    # Corners (v, vt, vn): 1/1/1, 2/2/1, 3/3/2, 1/5/1, 4/4/1 -> five vertices
    assert len(vertices) == 5 and triangles.tolist() == [[0, 1, 2], [3, 2, 4]]
    np.testing.assert_array_equal(vertices[[0, 3]], [[0, 0, 0], [0, 0, 0]])
    np.testing.assert_array_equal(uvs, [[0, 0], [1, 0], [1, 1], [0.5, 0.5], [0, 1]])
    np.testing.assert_array_equal(normals[2], [0, 0.6, 0.8])


def sphere_obj(corner: str) -> bytes:
    """The uv sphere's OBJ (seams at u = 0 and the poles), corners written as ``corner``
    (``{0}`` the 1-based index)."""
    v, t, n, uv = uv_sphere(10, 6)
    lines = [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in v]
    lines += [f"vt {a:.17g} {b:.17g}" for a, b in uv]
    lines += [f"vn {x:.17g} {y:.17g} {z:.17g}" for x, y, z in n]
    lines += ["f " + " ".join(corner.format(i + 1) for i in tri) for tri in t]
    return ("\n".join(lines) + "\n").encode()


@pytest.mark.parametrize("corner, has_uvs, has_normals", [
    ("{0}/{0}/{0}", True, True), ("{0}/{0}", True, False), ("{0}//{0}", False, True)])
def test_the_bulk_obj_reader_is_the_line_reader(corner, has_uvs, has_normals):
    """The vectorized reader gives the line-by-line reader's arrays (vertex order included)."""
    data = sphere_obj(corner)
    bulk, lines = _obj_corners_bulk(data), _parse_obj_corners(data, "sphere.obj")
    assert (bulk[2] is not None, bulk[3] is not None) == (has_uvs, has_normals)
    for a, b in zip(bulk, lines, strict=True):
        assert (a is None and b is None) or np.array_equal(a, b)


def test_relative_indices_go_to_the_line_reader():
    data = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf -3/-3 -2/-2 -1/-1\n"
    vertices, triangles, uvs, _ = parse_mesh(data, ".obj", name="rel.obj")
    np.testing.assert_array_equal(uvs, [[0, 0], [1, 0], [0, 1]])
    assert triangles.tolist() == [[0, 1, 2]]


def test_obj_without_attributes_and_mixed_attributes():
    _, _, uvs, normals = parse_mesh(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", ".obj", name="a")
    assert uvs is None and normals is None
    with pytest.raises(ValueError, match="some faces give texture coordinates"):
        parse_mesh(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\n"
                   b"f 1/1 2/1 3/1\nf 2 4 3\n", ".obj", name="mixed.obj")
    with pytest.raises(ValueError, match="mixed.obj:4: texture coordinate index 2"):
        parse_mesh(b"v 0 0 0\nv 1 0 0\nvt 0 0\nf 1/1 2/2 1/1\n", ".obj", name="mixed.obj")


def test_ply_texture_coordinates_and_normals():
    header = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
              "property float z\nproperty float nx\nproperty float ny\nproperty float nz\n"
              "property float s\nproperty float t\nelement face 1\n"
              "property list uchar int vertex_indices\nend_header\n")
    body = "0 0 0 0 0 1 0 0\n1 0 0 0 0 1 1 0\n0 1 0 0 1 0 0 1\n3 0 1 2\n"
    vertices, triangles, uvs, normals = parse_mesh((header + body).encode(), ".ply", name="p")
    np.testing.assert_array_equal(uvs, [[0, 0], [1, 0], [0, 1]])
    np.testing.assert_array_equal(normals, [[0, 0, 1], [0, 0, 1], [0, 1, 0]])


def mesh_scene(**mesh) -> dict:
    return {
        "camera": {"position": [0, 0, 3], "look_at": [0, 0, 0]},
        "film": {"width": 8, "height": 8},
        "materials": {"m": {"type": "diffuse"}},
        "objects": [{"type": "mesh", "vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]],
                     "triangles": [[0, 1, 2]], "material": "m", **mesh}],
    }


def test_inline_attribute_errors_name_the_field():
    with pytest.raises(SceneError) as info:
        load_scene(mesh_scene(uvs=[[0, 0], [1, 0]]))
    assert info.value.errors == [("objects[0].uvs", "uvs: 2 given for 3 vertices (one per "
                                  "vertex)")]
    with pytest.raises(SceneError) as info:
        load_scene(mesh_scene(normals=[[0, 0, 1], [0, 0, 0], [0, 0, 1]]))
    assert info.value.errors[0][0] == "objects[0].normals[1]"
    with pytest.raises(SceneError) as info:
        load_scene(mesh_scene(uvs=[[0, 0], [1], [0, 1]]))
    assert info.value.errors == [("objects[0].uvs[1]", "must have exactly 2 elements, not 1")]


def test_placed_normals_follow_the_inverse_transpose():
    """A normal n of a surface scaled by S becomes S⁻¹n (normalized): the plane x + y = 1 scaled
    by (2, 1, 1) is x/2 + y = 1, whose normal is along (1/2, 1, 0)."""
    scene = load_scene(mesh_scene(normals=[[1, 1, 0]] * 3, scale=[2, 1, 1],
                                  rotate={"axis": [0, 0, 1], "angle": 90}))
    n = scene.objects[0].normal_array()
    # then rotated by 90° about z: (½, 1, 0) -> (−1, ½, 0)
    expected = np.array([-1.0, 0.5, 0.0]) / np.linalg.norm([-1.0, 0.5, 0.0])
    np.testing.assert_allclose(n, [expected] * 3, atol=1e-12)


def test_normal_interpolation_against_numpy(rng):
    corners = rng.normal(size=(1, 9))
    n = (0.0, 0.0, 1.0)
    for b1, b2 in rng.dirichlet([1, 1, 1], 50)[:, 1:]:
        w = 1.0 - b1 - b2
        m = w * corners[0, 0:3] + b1 * corners[0, 3:6] + b2 * corners[0, 6:9]
        m /= np.linalg.norm(m)
        m = m if m[2] >= 0 else -m  # turned to the geometric normal's side
        np.testing.assert_allclose(interpolated_normal(corners, TRIANGLE, 0, b1, b2, n), m,
                                   atol=1e-12)
    # Without normals (NaN), or not a triangle: the geometric normal
    assert interpolated_normal(np.full((1, 9), np.nan), TRIANGLE, 0, 0.2, 0.2, n) == n
    assert interpolated_normal(corners, QUAD, 0, 0.2, 0.2, n) == n


def test_a_mesh_files_attributes_reach_the_scene_and_their_errors_name_the_file(tmp_path):
    header = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
              "property float z\nproperty float nx\nproperty float ny\nproperty float nz\n"
              "property float u\nproperty float v\nelement face 1\n"
              "property list uchar int vertex_indices\nend_header\n")
    good = "0 0 0 0 0 1 0 0\n1 0 0 0 0 1 1 0\n0 1 0 0 0 2 0 1\n3 0 1 2\n"
    (tmp_path / "tri.ply").write_text(header + good)
    scene = mesh_scene()
    scene["objects"][0] = {"type": "mesh", "path": "tri.ply", "material": "m"}
    mesh = load_scene(scene, allow_paths=True, base_dir=tmp_path).objects[0]
    np.testing.assert_array_equal(mesh.uv_array(), [[0, 0], [1, 0], [0, 1]])
    np.testing.assert_array_equal(mesh.normal_array(), [[0, 0, 1]] * 3)  # normalized
    (tmp_path / "tri.ply").write_text(header + good.replace("0 0 2 0 1", "0 0 0 0 1"))
    with pytest.raises(SceneError) as info:
        load_scene(scene, allow_paths=True, base_dir=tmp_path)
    assert info.value.errors == [("objects[0].path", "its normals: a zero vector cannot be a "
                                  "normal (vertex 2)")]


def test_box_faces_carry_the_documented_st():
    """A box face's (u, v) is its quad's (s, t) (docs/scene-format.md): −x (z, y), +x (y, z),
    −y (x, z), +y (z, x), −z (y, x), +z (x, y), each from the face's min corner."""
    from renderer.scene.compile import box_quads

    faces = box_quads((0, 0, 0), (1, 2, 3))
    axes = {"x": 0, "y": 1, "z": 2}
    for row, (s_axis, t_axis) in zip(faces, ["zy", "yz", "xz", "zx", "yx", "xy"], strict=True):
        assert np.flatnonzero(row[3:6])[0] == axes[s_axis] and row[3:6].min() >= 0
        assert np.flatnonzero(row[6:9])[0] == axes[t_axis] and row[6:9].min() >= 0
