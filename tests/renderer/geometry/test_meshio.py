"""Mesh files: OBJ and PLY readers against hand-written files, the writers, and a reference."""

import struct

import numpy as np
import pytest

from renderer.geometry import meshio
from renderer.geometry.meshio import (
    parse_obj,
    parse_obj_reference,
    read_mesh,
    write_obj,
    write_ply,
)

CUBE_OBJ = b"""\
# unit cube centred on the origin, quads wound counter-clockwise seen from outside
mtllib cube.mtl
o cube
v -0.5 -0.5 -0.5
v  0.5 -0.5 -0.5
v  0.5  0.5 -0.5
v -0.5  0.5 -0.5
v -0.5 -0.5  0.5
v  0.5 -0.5  0.5
v  0.5  0.5  0.5
v -0.5  0.5  0.5
vt 0 0
vn 0 0 1
usemtl white
s off
f 1 4 3 2
f 5 6 7 8
f 1 2 6 5
f 2 3 7 6
f 3 4 8 7
f 4 1 5 8
"""


def grid_mesh(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """An n x n vertex grid, jittered so coordinates need all 17 digits: 2 (n-1)^2 triangles."""
    rng = np.random.default_rng(seed)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    vertices = np.stack([i.ravel(), j.ravel(), np.zeros(n * n)], axis=1) + rng.random((n * n, 3))
    q = (i[:-1, :-1] * n + j[:-1, :-1]).ravel()
    triangles = np.concatenate(
        [np.stack([q, q + n, q + n + 1], axis=1), np.stack([q, q + n + 1, q + 1], axis=1)]
    )
    return vertices, triangles


@pytest.fixture
def fast_path_only(monkeypatch):
    """Fail if the OBJ reader falls back to the line-by-line parser: valid files must not need it,
    and a test that passed through the fallback would not be testing the vectorized code."""

    def refuse(*args, **kwargs):
        raise AssertionError("the OBJ fast path fell back to the reference parser")

    monkeypatch.setattr(meshio, "parse_obj_reference", refuse)


# --- OBJ ------------------------------------------------------------------------------------------


def test_obj_cube_quads_become_outward_triangles(tmp_path, fast_path_only):
    path = tmp_path / "cube.obj"
    path.write_bytes(CUBE_OBJ)
    vertices, triangles = read_mesh(path)
    assert vertices.dtype == np.float64 and vertices.shape == (8, 3)
    assert triangles.dtype == np.int64 and triangles.shape == (12, 3)
    # Fans around the first corner: f 1 4 3 2 -> (0, 3, 2), (0, 2, 1).
    assert triangles[:2].tolist() == [[0, 3, 2], [0, 2, 1]]
    # Counter-clockwise winding kept: every geometric normal points away from the centre.
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    normals = np.cross(b - a, c - a)
    centres = (a + b + c) / 3
    assert (np.einsum("ij,ij->i", normals, centres) > 0).all()
    # Each face of the cube is covered exactly twice (two triangles of area 1/2).
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0)


def test_obj_negative_indices_are_relative_to_their_line(fast_path_only):
    data = b"v 0 0 0\nv 1 0 0\nv 1 1 0\nf -3 -2 -1\nv 0 1 0\nf -4 -2 -1\nf 1/1/1 -3/2/2 4//3\n"
    _, triangles = parse_obj(data)
    assert triangles.tolist() == [[0, 1, 2], [0, 2, 3], [0, 1, 3]]


@pytest.mark.parametrize("form", [b"{}", b"{}/{}", b"{}//{}", b"{}/{}/{}"])
def test_obj_reference_forms(form, fast_path_only):
    refs = [form.replace(b"{}", str(i).encode()) for i in (1, 2, 3, 4)]
    data = b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\nf " + b" ".join(refs) + b"\n"
    _, triangles = parse_obj(data)
    assert triangles.tolist() == [[0, 1, 2], [0, 2, 3]]


def test_obj_mixed_forms_comments_crlf_and_indentation(fast_path_only):
    data = (
        b"v 0 0 0 1.0\r\n  v 1 0 0 # a comment\r\nv 1 1 0 0.5 0.5 0.5\r\n\tv 0 1 0\r\n"
        b"f 1 2 3\r\n f 1/1 3/1 4/1 # another\r\nf 1//2 2//2 3//2 4//2\r\n"
    )
    vertices, triangles = parse_obj(data)
    assert vertices.tolist() == [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]
    assert triangles.tolist() == [[0, 1, 2], [0, 2, 3], [0, 1, 2], [0, 2, 3]]


def test_obj_fast_path_matches_reference_on_a_messy_file(monkeypatch):
    # Polygons of 3..7 sides, every reference form, relative indices and interleaved v lines:
    # the vectorized parser must agree with the line-by-line one exactly.
    rng = np.random.default_rng(5)
    lines, n_vertices = [], 0
    for _ in range(400):
        for _ in range(rng.integers(0, 4)):
            lines.append(b"v %r %r %r" % tuple(rng.standard_normal(3).tolist()))
            n_vertices += 1
        if n_vertices < 3:
            continue
        refs = []
        for index in rng.integers(0, n_vertices, rng.integers(3, 8)):
            ref = int(index) + 1 if rng.random() < 0.5 else int(index) - n_vertices
            refs.append([b"%d", b"%d/7", b"%d//7", b"%d/7/7"][rng.integers(4)] % ref)
        lines.append(b"f " + b" ".join(refs))
        lines.append([b"vt 0 0", b"# note", b"g part", b""][rng.integers(4)])
    data = b"\n".join(lines)
    ref_vertices, ref_triangles = parse_obj_reference(data.split(b"\n"))
    monkeypatch.setattr(meshio, "parse_obj_reference", None)  # no fallback allowed
    vertices, triangles = parse_obj(data)
    assert np.array_equal(vertices, ref_vertices)
    assert np.array_equal(triangles, ref_triangles)
    assert len(triangles) > 1000


@pytest.mark.parametrize(
    ("data", "line", "message"),
    [
        (b"v 0 0 0\nv 1 0 0\nv 1 1 0\n\nf 1 2 4\n", 5, "vertex index 4"),
        (b"v 0 0 0\nv 1 0 0\nv 1 x 0\nf 1 2 3\n", 3, "bad vertex coordinate"),
        (b"v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2\n", 4, "at least 3"),
        (b"v 0 0 0\nv 1 0 0\nv 1 1 0\nf 0 1 2\n", 4, "index 0"),
        (b"v 0 0 0\nf -2 -1 -1\n", 2, "before the first vertex"),
        (b"v 0 0 0\nv 1 0 nan\nv 1 1 0\nf 1 2 3\n", 2, "not finite"),
        (b"v 0 0\nf 1 1 1\n", 1, "x, y and z"),
        (b"v 0 0 0\nf 1/1 /2 1\n", 2, "bad vertex reference"),
    ],
)
def test_obj_errors_name_file_and_line(tmp_path, data, line, message):
    path = tmp_path / "bad.obj"
    path.write_bytes(data)
    with pytest.raises(ValueError, match=rf"bad\.obj:{line}: .*{message}"):
        read_mesh(path)


# --- PLY ------------------------------------------------------------------------------------------

_STRUCT = {
    "char": "b", "uchar": "B", "short": "h", "ushort": "H", "int": "i", "uint": "I",
    "float": "f", "double": "d", "int8": "b", "uint8": "B", "int16": "h", "uint16": "H",
    "int32": "i", "uint32": "I", "float32": "f", "float64": "d",
}  # fmt: skip


def encode_ply(fmt: str, elements: list) -> bytes:
    """An independent PLY encoder for tests, one record at a time with `struct`.

    `elements` is [(name, [(type, name) or ("list", count type, item type, name)], rows)], each
    row a list of values (a list for a list property).
    """
    header = [f"ply\nformat {fmt} 1.0\ncomment test file\n"]
    body = []
    endian = "<" if fmt == "binary_little_endian" else ">"
    for name, props, rows in elements:
        header.append(f"element {name} {len(rows)}\n")
        header += [f"property {' '.join(p)}\n" for p in props]
        for row in rows:
            fields = []
            for prop, value in zip(props, row, strict=True):
                if prop[0] == "list":
                    fields.append((prop[1], len(value)))
                    fields += [(prop[2], v) for v in value]
                else:
                    fields.append((prop[0], value))
            if fmt == "ascii":
                body.append(" ".join(repr(v) for _, v in fields).encode() + b"\n")
            else:
                body += [struct.pack(endian + _STRUCT[t], v) for t, v in fields]
    return "".join(header + ["end_header\n"]).encode() + b"".join(body)


FORMATS = ["ascii", "binary_little_endian", "binary_big_endian"]


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("vertex_type", ["double", "float"])
def test_ply_writer_round_trip(tmp_path, fmt, vertex_type):
    vertices, triangles = grid_mesh(12)
    write_ply(tmp_path / "m.ply", vertices, triangles, format=fmt, vertex_type=vertex_type)
    back_vertices, back_triangles = read_mesh(tmp_path / "m.ply")
    expected = vertices if vertex_type == "double" else vertices.astype(np.float32)
    assert back_vertices.dtype == np.float64 and back_triangles.dtype == np.int64
    assert np.array_equal(back_vertices, expected)
    assert np.array_equal(back_triangles, triangles)


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize(
    ("xyz_type", "count_type", "index_type", "index_name"),
    [
        ("float", "uchar", "int", "vertex_indices"),
        ("double", "uint8", "uint32", "vertex_index"),
        ("short", "ushort", "short", "vertex_indices"),
        ("int", "int", "uint", "vertex_index"),
        ("uchar", "uint", "ushort", "vertex_indices"),
    ],
)
def test_ply_types_extra_properties_and_elements(
    tmp_path, fmt, xyz_type, count_type, index_type, index_name
):
    coords = [[0, 0, 0], [2, 0, 0], [2, 2, 0], [0, 2, 0], [1, 3, 0]]
    vertex_props = [("float", "nx"), (xyz_type, "x"), (xyz_type, "y"), ("uchar", "red")]
    vertex_props += [(xyz_type, "z"), ("list", "uchar", "float", "uv")]
    vertex_rows = [[0.5, x, y, 200, z, [0.25] * (k % 3)] for k, (x, y, z) in enumerate(coords)]
    faces = [[0, 1, 2], [0, 2, 3], [3, 2, 4]]
    elements = [
        ("camera", [("float", "fov")], [[0.5], [0.75]]),  # before the vertices: skipped
        ("vertex", vertex_props, vertex_rows),
        ("face", [("uchar", "flags"), ("list", count_type, index_type, index_name)],
         [[1, f] for f in faces]),
        ("edge", [("int", "a"), ("int", "b")], [[0, 1]]),
    ]  # fmt: skip
    (tmp_path / "m.ply").write_bytes(encode_ply(fmt, elements))
    vertices, triangles = read_mesh(tmp_path / "m.ply")
    assert vertices.tolist() == coords
    assert triangles.tolist() == faces


@pytest.mark.parametrize("fmt", FORMATS)
def test_ply_mixed_polygons_are_fanned(tmp_path, fmt):
    # Records of different sizes take the record-by-record path in binary files.
    angles = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    coords = np.stack([np.cos(angles), np.sin(angles), 0 * angles], axis=1).tolist()
    faces = [[0, 1, 2, 3], [0, 3, 4], [4, 5, 6, 7, 0]]
    elements = [
        ("vertex", [("float", "x"), ("float", "y"), ("float", "z")], coords),
        ("face", [("list", "uchar", "int", "vertex_indices"), ("uchar", "flags")],
         [[f, 0] for f in faces]),
    ]  # fmt: skip
    (tmp_path / "m.ply").write_bytes(encode_ply(fmt, elements))
    vertices, triangles = read_mesh(tmp_path / "m.ply")
    assert np.array_equal(vertices, np.array(coords, np.float32))
    assert triangles.tolist() == [[0, 1, 2], [0, 2, 3], [0, 3, 4], [4, 5, 6], [4, 6, 7], [4, 7, 0]]


def test_ply_all_quads_take_the_fixed_size_path(tmp_path):
    vertices = np.arange(12.0).reshape(4, 3)
    elements = [
        ("vertex", [("double", "x"), ("double", "y"), ("double", "z")], vertices.tolist()),
        ("face", [("list", "uchar", "int", "vertex_indices")], [[[0, 1, 2, 3]], [[3, 2, 1, 0]]]),
    ]
    (tmp_path / "q.ply").write_bytes(encode_ply("binary_little_endian", elements))
    _, triangles = read_mesh(tmp_path / "q.ply")
    assert triangles.tolist() == [[0, 1, 2], [0, 2, 3], [3, 2, 1], [3, 1, 0]]


def test_ply_point_cloud_has_no_triangles(tmp_path):
    elements = [("vertex", [("float", "x"), ("float", "y"), ("float", "z")], [[1, 2, 3]])]
    (tmp_path / "p.ply").write_bytes(encode_ply("ascii", elements))
    vertices, triangles = read_mesh(tmp_path / "p.ply")
    assert vertices.tolist() == [[1, 2, 3]] and triangles.shape == (0, 3)


def test_ply_errors(tmp_path):
    vertex = ("vertex", [("float", "x"), ("float", "y"), ("float", "z")], [[0, 0, 0]] * 3)
    face = ("face", [("list", "uchar", "int", "vertex_indices")], [[[0, 1, 3]]])
    path = tmp_path / "bad.ply"
    path.write_bytes(encode_ply("binary_little_endian", [vertex, face]))
    with pytest.raises(ValueError, match=r"bad\.ply: PLY face 0 refers to vertex 3"):
        read_mesh(path)
    good = encode_ply("binary_little_endian", [vertex, (face[0], face[1], [[[0, 1, 2]]])])
    path.write_bytes(good[:-3])
    with pytest.raises(ValueError, match=r"bad\.ply: PLY data ends inside element 'face'"):
        read_mesh(path)
    path.write_bytes(good.replace(b"property float y", b"property flaot y"))
    with pytest.raises(ValueError, match=r"bad\.ply:6: bad property line"):
        read_mesh(path)
    path.write_bytes(b"plx\n" + good[4:])
    with pytest.raises(ValueError, match="not a PLY file"):
        read_mesh(path)


def test_unknown_extension(tmp_path):
    with pytest.raises(ValueError, match=r"\.obj, \.ply"):
        read_mesh(tmp_path / "mesh.stl")


# --- writers and a million triangles --------------------------------------------------------------


def test_obj_writer_round_trip(tmp_path, fast_path_only):
    vertices, triangles = grid_mesh(20)
    write_obj(tmp_path / "m.obj", vertices, triangles)
    back_vertices, back_triangles = read_mesh(tmp_path / "m.obj")
    assert np.array_equal(back_vertices, vertices)
    assert np.array_equal(back_triangles, triangles)


@pytest.fixture(scope="module")
def million_triangles() -> tuple[np.ndarray, np.ndarray]:
    vertices, triangles = grid_mesh(708)  # 501,264 vertices, 999,698 triangles
    assert len(triangles) > 999_000
    return vertices, triangles


@pytest.mark.slow
@pytest.mark.parametrize("ext", [".ply", ".obj"])
def test_million_triangle_round_trip(tmp_path, million_triangles, ext, fast_path_only):
    vertices, triangles = million_triangles
    path = tmp_path / f"big{ext}"
    (write_ply if ext == ".ply" else write_obj)(path, vertices, triangles)
    back_vertices, back_triangles = read_mesh(path)
    assert np.array_equal(back_vertices, vertices)
    assert np.array_equal(back_triangles, triangles)
