"""File references (scene format v1.1, "Files: paths and assets"): renderer/scene/files.py."""

import hashlib

import numpy as np
import pytest

from renderer.geometry.meshio import write_obj, write_ply
from renderer.scene import SceneError, load_scene, load_scene_file
from renderer.scene.files import FileSource, digest, local_assets, sniff, store_local_asset
from renderer.scene.schema import AssetRef

TET_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
TET_T = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], dtype=np.int64)


def scene_with(mesh: dict) -> dict:
    return {
        "camera": {"position": [0, 0, 5], "look_at": [0, 0, 0]},
        "film": {"width": 8, "height": 8},
        "materials": {"wax": {"type": "translucent", "albedo": [0.9, 0.9, 0.9], "density": 2}},
        "objects": [{"type": "mesh", "material": "wax", **mesh}],
        "lights": [{"type": "point", "position": [0, 3, 3], "intensity": [5, 5, 5]}],
    }


@pytest.fixture
def obj_bytes(tmp_path):
    write_obj(tmp_path / "tet.obj", TET_V, TET_T)
    return (tmp_path / "tet.obj").read_bytes()


@pytest.fixture
def ply_bytes(tmp_path):
    write_ply(tmp_path / "tet.ply", TET_V, TET_T)
    return (tmp_path / "tet.ply").read_bytes()


def errors_of(data, **kwargs):
    with pytest.raises(SceneError) as info:
        load_scene(data, **kwargs)
    return info.value.errors


def test_sniff_tells_each_kind_by_its_bytes(obj_bytes, ply_bytes):
    assert sniff(obj_bytes) == ".obj"
    assert sniff(b"# a comment\n\no cube\nv 0 0 0\n") == ".obj"
    assert sniff(ply_bytes) == ".ply"
    assert sniff(b"\x89PNG\r\n\x1a\n....") == ".png"
    assert sniff(b"\x76\x2f\x31\x01\x02\x00\x00\x00") == ".exr"
    assert sniff(b"PF\n2 2\n-1.0\n") == ".pfm"
    assert sniff(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n") == ".hdr"
    assert sniff(b"hello world\n") == ""
    assert sniff(b"\x00\x01\x02v 1 2 3") == ""


def test_asset_mesh_renders_as_its_inline_twin(obj_bytes, ply_bytes):
    inline = load_scene(scene_with({"vertices": TET_V.tolist(), "triangles": TET_T.tolist()}))
    for data in (obj_bytes, ply_bytes):
        name = digest(data)
        assert name == "sha256:" + hashlib.sha256(data).hexdigest()
        scene = load_scene(scene_with({"asset": name}), assets={name: data}.__getitem__)
        v, t = scene.objects[0].arrays()
        np.testing.assert_array_equal(v, inline.objects[0].arrays()[0])
        np.testing.assert_array_equal(t, inline.objects[0].arrays()[1])
        assert scene.objects[0].source_path is None
        # It keeps its reference when serialized (whoever reads the scene fetches the asset).
        dumped = scene.model_dump(mode="json", exclude_none=True)["objects"][0]
        assert dumped["asset"] == name and "vertices" not in dumped


def test_unknown_asset_and_no_asset_store_are_named(obj_bytes):
    name = digest(obj_bytes)
    assert errors_of(scene_with({"asset": name}), assets={}.__getitem__) == [
        ("objects[0].asset", f"unknown asset {name} (upload it first: POST /api/assets)")
    ]
    assert errors_of(scene_with({"asset": name})) == [
        ("objects[0].asset", f"{name}: assets cannot be read here (no asset store)")
    ]


def test_asset_bytes_must_match_their_name(obj_bytes):
    name = digest(obj_bytes)
    tampered = obj_bytes.replace(b"v 1 0 0", b"v 9 0 0")
    assert tampered != obj_bytes
    assert errors_of(scene_with({"asset": name}), assets={name: tampered}.__getitem__) == [
        ("objects[0].asset", f"{name}: the stored bytes do not match their SHA-256")
    ]


def test_asset_of_the_wrong_kind_is_named():
    png = b"\x89PNG\r\n\x1a\n" + bytes(32)
    name = digest(png)
    assert errors_of(scene_with({"asset": name}), assets={name: png}.__getitem__) == [
        ("objects[0].asset", f"{name}: a PNG file; expected OBJ, PLY")
    ]


@pytest.mark.parametrize("value", ["sha256:abc", "sha256:" + "A" * 64, "md5:" + "0" * 32])
def test_malformed_asset_name(value):
    assert errors_of(scene_with({"asset": value}), assets={}.__getitem__) == [
        ("objects[0].asset",
         'must be "sha256:" and 64 lowercase hex digits (the SHA-256 of the file)')
    ]
    assert errors_of(scene_with({"asset": 12}), assets={}.__getitem__) == [
        ("objects[0].asset", "must be a string")
    ]


def test_asset_with_path_or_inline_is_refused(obj_bytes):
    name = digest(obj_bytes)
    errors = errors_of(
        scene_with({"asset": name, "path": "tet.obj"}), allow_paths=True, assets={}.__getitem__
    )
    assert errors == [("objects[0]", "give one of vertices and triangles, path or asset, not path "
                       "and asset")]


def test_path_extension_must_agree_with_content(tmp_path, ply_bytes):
    (tmp_path / "liar.obj").write_bytes(ply_bytes)
    path = str((tmp_path / "liar.obj").resolve())
    assert errors_of(scene_with({"path": "liar.obj"}), allow_paths=True, base_dir=tmp_path) == [
        ("objects[0].path", f"{path}: its content is PLY, not .obj")
    ]


def test_file_source_refuses_paths_unless_allowed(tmp_path, obj_bytes):
    (tmp_path / "tet.obj").write_bytes(obj_bytes)
    assert FileSource().read("tet.obj", "x", (".obj",)) == [
        ("x", "file paths are accepted only by the command line")
    ]
    data, kind, label = FileSource(allow_paths=True, base_dir=tmp_path).read(
        "tet.obj", "x", (".obj",)
    )
    assert (data, kind, label) == (obj_bytes, ".obj", str((tmp_path / "tet.obj").resolve()))
    ref = AssetRef(asset=digest(obj_bytes))
    assert FileSource(assets={ref.asset: obj_bytes}.__getitem__).read(ref, "y", (".obj",)) == (
        obj_bytes, ".obj", ref.asset
    )


def test_cli_reads_assets_from_the_local_folder(tmp_path, monkeypatch, obj_bytes):
    folder = tmp_path / "assets"
    monkeypatch.setenv("LUCENT_ASSET_DIR", str(folder))
    name = store_local_asset(obj_bytes)
    assert name == digest(obj_bytes)
    assert (folder / name.removeprefix("sha256:")).read_bytes() == obj_bytes
    assert store_local_asset(obj_bytes) == name  # idempotent
    assert local_assets()(name) == obj_bytes
    with pytest.raises(KeyError):
        local_assets()("sha256:" + "0" * 64)
    with pytest.raises(KeyError):
        local_assets()("../../etc/passwd")

    import json

    scene_file = tmp_path / "scene.json"
    scene_file.write_text(json.dumps(scene_with({"asset": name})))
    scene = load_scene_file(scene_file)
    np.testing.assert_array_equal(scene.objects[0].arrays()[0], TET_V)
