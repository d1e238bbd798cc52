"""``environment`` in a scene: the image read from a path or an asset, every fault named by its
field (a bad file, NaN or negative texels, the size limits, exclusivity with ``background``)."""

from __future__ import annotations

import numpy as np
import pytest

from renderer.film.image_io import encode_exr, encode_pfm
from renderer.scene import SceneError, load_scene
from renderer.scene.files import digest
from renderer.scene.limits import Limits


def doc(environment, **extra) -> dict:
    return {
        "camera": {"position": [0, 0, 4], "look_at": [0, 0, 0]},
        "film": {"width": 8, "height": 8},
        "environment": environment,
        "materials": {"w": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
        "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "w"}],
        **extra,
    }


def errors(data, **kwargs) -> list[tuple[str, str]]:
    with pytest.raises(SceneError) as info:
        load_scene(data, **kwargs)
    return info.value.errors


@pytest.fixture
def sky() -> np.ndarray:
    return np.random.default_rng(1).random((8, 16, 3)).astype(np.float32)


def test_path_and_asset_read_the_same_pixels(tmp_path, sky):
    (tmp_path / "sky.exr").write_bytes(encode_exr(sky, compression="ZIP"))
    by_path = load_scene(doc({"image": "sky.exr", "scale": 2.0}), allow_paths=True,
                         base_dir=tmp_path)
    assert np.array_equal(by_path.environment.pixels(), sky)
    data = encode_pfm(sky)
    name = digest(data)
    by_asset = load_scene(doc({"image": {"asset": name}}), assets={name: data}.__getitem__)
    assert np.array_equal(by_asset.environment.pixels(), sky)
    assert by_path.environment.scale == 2.0 and by_asset.environment.scale == 1.0


def test_paths_are_refused_without_allow_paths(sky):
    assert errors(doc({"image": "sky.exr"}))[0][0] == "environment.image"


def test_exclusive_with_background(tmp_path, sky):
    (tmp_path / "sky.pfm").write_bytes(encode_pfm(sky))
    got = errors(doc({"image": "sky.pfm"}, background=[0.1, 0.1, 0.1]), allow_paths=True,
                 base_dir=tmp_path)
    assert got == [("environment", "exclusive with background: give one or the other")]


@pytest.mark.parametrize("fault", ["truncated", "not_an_image", "png", "nan", "inf", "negative",
                                   "one_row", "channels"])
def test_bad_images_are_named(tmp_path, sky, fault):
    data = encode_exr(sky)
    expect = {"truncated": "truncated or corrupt", "not_an_image": "not a file of a known kind",
              "png": "a PNG file; expected EXR, PFM, HDR", "nan": "not finite",
              "inf": "not finite", "negative": "negative", "one_row": "at least 2 rows",
              "channels": "no R, G, B or Y channels"}[fault]
    if fault == "truncated":
        data = data[: len(data) - 100]
    elif fault == "not_an_image":
        data = b"\x00\x01hello"
    elif fault == "png":
        data = b"\x89PNG\r\n\x1a\n" + data
    elif fault in ("nan", "inf", "negative"):
        sky[3, 5, 1] = {"nan": np.nan, "inf": np.inf, "negative": -0.5}[fault]
        data = encode_pfm(sky)
    elif fault == "one_row":
        data = encode_pfm(sky[:1])
    elif fault == "channels":
        import io

        import OpenEXR

        buffer = io.BytesIO()
        OpenEXR.File({}, {"A": np.ones((4, 4), np.float32)}).write(buffer)
        data = buffer.getvalue()
    name = digest(data)
    got = errors(doc({"image": {"asset": name}}), assets={name: data}.__getitem__)
    assert len(got) == 1 and got[0][0] == "environment.image.asset", got
    assert expect in got[0][1], got
    if fault in ("nan", "negative"):
        assert "row 3, column 5" in got[0][1]


def test_limits_are_enforced_and_named(sky):
    data = encode_pfm(sky)  # 16 x 8
    name = digest(data)
    read = {name: data}.__getitem__
    got = errors(doc({"image": {"asset": name}}), assets=read,
                 limits=Limits(max_environment_side=15))
    assert got[0][0] == "environment.image.asset"
    assert "16x8 texels exceed the limit 15 per side (LUCENT_MAX_ENVIRONMENT_SIDE)" in got[0][1]
    got = errors(doc({"image": {"asset": name}}), assets=read, limits=Limits(max_texels=127))
    assert "16x8 = 128 texels exceed the limit 127 (LUCENT_MAX_TEXELS)" in got[0][1]
    assert load_scene(doc({"image": {"asset": name}}), assets=read,
                      limits=Limits(max_texels=128, max_environment_side=16))


def test_schema_fields(sky):
    got = errors(doc({"image": {"asset": digest(b"x")}, "scale": -1}))
    assert got[0][0] == "environment.scale"
    got = errors(doc({"image": {"asset": digest(b"x")}, "rotate": {"axis": [0, 0, 0],
                                                                    "angle": 3}}))
    assert got[0][0] == "environment.rotate.axis"
    got = errors(doc({"image": {"asset": digest(b"x")}, "exposure": 1}))
    assert got[0][0] == "environment.exposure"
