"""Textures (renderer/textures.py): lookups against a NumPy reference, (u, v) of every shape, image
decoding (sRGB, 16-bit PNG), and the errors a bad texture gets (scene format v1.1)."""

from __future__ import annotations

import io
import math
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from renderer.film.image_io import decode_png, decode_texture, encode_exr, encode_pfm
from renderer.film.tonemap import srgb_to_linear
from renderer.geometry.shapes import QUAD, SPHERE, TRIANGLE
from renderer.scene.limits import Limits
from renderer.scene.load import SceneError, load_scene
from renderer.textures import (
    BITMAP,
    CHECKERBOARD,
    COLOR0,
    COLOR1,
    HEIGHT,
    KIND,
    OFFSET,
    OU,
    SU,
    TEX_ROW,
    WIDTH,
    sphere_uv,
    surface_uv,
    texture_eval,
)

# --- lookups against NumPy ------------------------------------------------------------------------


def bilinear_reference(image: np.ndarray, u, v, scale=(1.0, 1.0), offset=(0.0, 0.0)):
    """Bilinear between texel centres, repeating; v upwards (row 0 is the image's top)."""
    h, w, _ = image.shape
    x = (u * scale[0] + offset[0]) * w - 0.5
    y = (1.0 - (v * scale[1] + offset[1])) * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    i0, j0 = np.mod(x0, w).astype(int), np.mod(y0, h).astype(int)
    i1, j1 = (i0 + 1) % w, (j0 + 1) % h
    return ((1 - fx) * (1 - fy) * image[j0, i0] + fx * (1 - fy) * image[j0, i1]
            + (1 - fx) * fy * image[j1, i0] + fx * fy * image[j1, i1])


def bitmap_row(image, scale=(1.0, 1.0), offset=(0.0, 0.0)):
    row = np.zeros((1, TEX_ROW))
    row[0, KIND], row[0, OFFSET] = BITMAP, 0
    row[0, WIDTH], row[0, HEIGHT] = image.shape[1], image.shape[0]
    row[0, SU:SU + 2], row[0, OU:OU + 2] = scale, offset
    return row, np.ascontiguousarray(image, np.float32).reshape(-1)


def lookup(row, texels, u, v):
    return np.array([texture_eval(row, texels, 0, a, b) for a, b in zip(u, v, strict=True)])


@pytest.mark.parametrize("scale, offset", [((1.0, 1.0), (0.0, 0.0)), ((2.5, -1.5), (0.3, 0.7))])
def test_bitmap_lookup_is_bilinear_and_repeats(rng, scale, offset):
    image = rng.random((5, 7, 3)).astype(np.float32)
    row, texels = bitmap_row(image, scale, offset)
    u, v = rng.uniform(-3.0, 3.0, 500), rng.uniform(-3.0, 3.0, 500)
    expected = bilinear_reference(image.astype(np.float64), u, v, scale, offset)
    np.testing.assert_allclose(lookup(row, texels, u, v), expected, rtol=1e-6, atol=1e-6)


def test_bitmap_texel_centres_and_orientation():
    """(0, 0) is the bottom-left corner as displayed: the centre of the top-left texel is at
    (½W⁻¹, 1 − ½H⁻¹); a flipped u or v would read another texel."""
    image = np.zeros((2, 3, 3), np.float32)
    image[0, 0] = [1, 0, 0]  # top-left
    image[1, 2] = [0, 0, 1]  # bottom-right
    row, texels = bitmap_row(image)
    np.testing.assert_allclose(texture_eval(row, texels, 0, 1 / 6, 3 / 4), [1, 0, 0], atol=1e-7)
    np.testing.assert_allclose(texture_eval(row, texels, 0, 5 / 6, 1 / 4), [0, 0, 1], atol=1e-7)
    # Half-way between the first and last column: wrapping blends the two
    np.testing.assert_allclose(texture_eval(row, texels, 0, 0.0, 3 / 4), [0.5, 0, 0], atol=1e-7)


def test_checkerboard_parity(rng):
    row = np.zeros((1, TEX_ROW))
    row[0, KIND] = CHECKERBOARD
    row[0, SU:SU + 2] = (3.0, 2.0)
    row[0, COLOR0:COLOR0 + 3] = (1.0, 0.5, 0.25)
    row[0, COLOR1:COLOR1 + 3] = (0.1, 0.2, 0.3)
    u, v = rng.uniform(-2.0, 2.0, 400), rng.uniform(-2.0, 2.0, 400)
    even = (np.floor(3.0 * u) + np.floor(2.0 * v)) % 2 == 0
    expected = np.where(even[:, None], [1.0, 0.5, 0.25], [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(lookup(row, np.zeros(0, np.float32), u, v), expected)


# --- (u, v) of the shapes -------------------------------------------------------------------------


@pytest.mark.parametrize("d, uv", [((1, 0, 0), (0.25, 0.5)), ((0, 0, -1), (0.0, 0.5)),
                                   ((-1, 0, 0), (0.75, 0.5)), ((0, 0, 1), (0.5, 0.5)),
                                   ((0, 1, 0), (None, 1.0)), ((0, -1, 0), (None, 0.0))])
def test_sphere_parametrization(d, uv):
    """u = atan2(d.x, −d.z)/(2π) mod 1, v = 1 − acos(d.y)/π (scene format v1.1)."""
    u, v = sphere_uv(tuple(float(x) for x in d))
    if uv[0] is not None:
        assert u == pytest.approx(uv[0], abs=1e-12)
    assert v == pytest.approx(uv[1], abs=1e-12)


def test_sphere_parametrization_general(rng):
    d = rng.normal(size=(200, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    for x in d:
        u, v = sphere_uv(tuple(x))
        assert u == pytest.approx(np.mod(np.arctan2(x[0], -x[2]) / (2 * np.pi), 1.0), abs=1e-12)
        assert v == pytest.approx(1.0 - np.arccos(x[1]) / np.pi, abs=1e-12)


def test_quad_and_triangle_uv():
    none = np.zeros((0, 6))
    n = (0.0, 0.0, 1.0)
    assert surface_uv(QUAD, none, 0, 0.3, 0.8, n) == (0.3, 0.8)  # a quad's (s, t)
    assert surface_uv(TRIANGLE, none, 0, 0.3, 0.2, n) == (0.3, 0.2)  # no uvs: barycentrics
    corners = np.array([[0.1, 0.2, 0.9, 0.3, 0.4, 0.8]])
    u, v = surface_uv(TRIANGLE, corners, 0, 0.25, 0.5, n)
    w = 0.25
    assert u == pytest.approx(w * 0.1 + 0.25 * 0.9 + 0.5 * 0.4)
    assert v == pytest.approx(w * 0.2 + 0.25 * 0.3 + 0.5 * 0.8)
    assert surface_uv(SPHERE, none, 0, 0.0, 0.0, (1.0, 0.0, 0.0))[0] == pytest.approx(0.25)


# --- image decoding -------------------------------------------------------------------------------


def png16(values: np.ndarray, filters=(0, 1, 2, 3, 4)) -> bytes:
    """A 16-bit RGB PNG of ``values`` (H, W, 3 uint16), each row filtered with the next of
    ``filters`` (PNG specification 9.2), so that decoding must undo every filter type."""
    h, w, _ = values.shape
    raw = values.astype(">u2").view(np.uint8).reshape(h, w * 6).astype(np.int64)
    out = bytearray()
    for y in range(h):
        f = filters[y % len(filters)]
        line = raw[y]
        prev = raw[y - 1] if y > 0 else np.zeros_like(line)
        a = np.concatenate([np.zeros(6, np.int64), line[:-6]])
        c = np.concatenate([np.zeros(6, np.int64), prev[:-6]])
        if f == 0:
            enc = line
        elif f == 1:
            enc = line - a
        elif f == 2:
            enc = line - prev
        elif f == 3:
            enc = line - (a + prev) // 2
        else:
            p = a + prev - c
            pa, pb, pc = np.abs(p - a), np.abs(p - prev), np.abs(p - c)
            enc = line - np.where((pa <= pb) & (pa <= pc), a, np.where(pb <= pc, prev, c))
        out += bytes([f]) + (enc % 256).astype(np.uint8).tobytes()

    def chunk(kind, data):
        crc = struct.pack(">I", zlib.crc32(kind + data))
        return struct.pack(">I", len(data)) + kind + data + crc

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(bytes(out))) + chunk(b"IEND", b""))


def test_png16_every_filter(rng):
    values = rng.integers(0, 65536, (10, 9, 3)).astype(np.uint16)
    decoded = decode_png(png16(values), name="t.png")
    np.testing.assert_array_equal(decoded, values.astype(np.float32) / 65535.0)


def test_png_srgb_decoding():
    """8-bit sRGB texels are decoded to linear with the sRGB curve (IEC 61966-2-1); srgb false
    keeps the encoded values."""
    values = np.array([[[0, 10, 128], [200, 255, 64]]], np.uint8)
    buffer = io.BytesIO()
    Image.fromarray(values).save(buffer, format="PNG")
    c = values / 255.0
    expected = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    np.testing.assert_allclose(decode_texture(buffer.getvalue(), ".png", srgb=None, name="t"),
                               expected, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(decode_texture(buffer.getvalue(), ".png", srgb=False, name="t"),
                               c, rtol=1e-6)
    sixteen = decode_texture(png16(np.full((1, 1, 3), 32768, np.uint16)), ".png", srgb=True,
                             name="t")
    np.testing.assert_allclose(sixteen, srgb_to_linear(np.float32(32768 / 65535)), rtol=1e-6)


# --- scenes with textures: loading and errors -----------------------------------------------------


def textured_scene(albedo, **extra) -> dict:
    scene = {
        "camera": {"position": [0.5, 0.5, 2.0], "look_at": [0.5, 0.5, 0.0], "fov": 40},
        "film": {"width": 16, "height": 16},
        "render": {"spp": 4, "max_depth": 1},
        "background": [1.0, 1.0, 1.0],
        "materials": {"m": {"type": "diffuse", "albedo": albedo}},
        "objects": [{"type": "quad", "origin": [0, 0, 0], "edge1": [1, 0, 0],
                     "edge2": [0, 1, 0], "material": "m"}],
    }
    scene.update(extra)
    return scene


def bitmap(image: str, **extra) -> dict:
    return {"type": "bitmap", "image": image, **extra}


def load(tmp_path: Path, scene: dict, **kwargs):
    return load_scene(scene, allow_paths=True, base_dir=tmp_path, **kwargs)


def errors_of(tmp_path: Path, scene: dict, **kwargs) -> list[tuple[str, str]]:
    with pytest.raises(SceneError) as info:
        load(tmp_path, scene, **kwargs)
    return info.value.errors


FIELD = "materials.m.albedo.image"


def test_bitmap_is_read_and_checked(tmp_path):
    Image.fromarray(np.full((4, 4, 3), 128, np.uint8)).save(tmp_path / "grey.png")
    scene = load(tmp_path, textured_scene(bitmap("grey.png", scale=[2, 2])))
    assert scene.materials["m"].albedo.pixels().shape == (4, 4, 3)


@pytest.mark.parametrize("content, message", [
    (b"\x89PNG\r\n\x1a\n" + b"\x00" * 40, "PNG"),  # truncated after the signature
    (b"hello, world\n", "not a PNG file"),
])
def test_bad_image_files_name_the_field(tmp_path, content, message):
    (tmp_path / "bad.png").write_bytes(content)
    errors = errors_of(tmp_path, textured_scene(bitmap("bad.png")))
    assert errors[0][0] == FIELD and message in errors[0][1], errors


def test_truncated_png_names_the_field(tmp_path):
    buffer = io.BytesIO()
    Image.fromarray(np.random.default_rng(1).integers(0, 255, (32, 32, 3), np.uint8)).save(
        buffer, format="PNG")
    (tmp_path / "cut.png").write_bytes(buffer.getvalue()[:200])
    errors = errors_of(tmp_path, textured_scene(bitmap("cut.png")))
    assert errors[0][0] == FIELD and "truncated" in errors[0][1], errors


def test_nan_texels_and_wrong_channels_name_the_field(tmp_path):
    image = np.full((2, 2, 3), 0.5, np.float32)
    image[1, 0, 2] = np.nan
    (tmp_path / "nan.pfm").write_bytes(encode_pfm(image))
    errors = errors_of(tmp_path, textured_scene(bitmap("nan.pfm")))
    assert errors[0][0] == FIELD and "not finite" in errors[0][1], errors

    import OpenEXR  # an EXR with an alpha channel only: no colour to read

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    path = tmp_path / "alpha.exr"
    OpenEXR.File(header, {"A": np.ones((2, 2), np.float32)}).write(str(path))
    errors = errors_of(tmp_path, textured_scene(bitmap("alpha.exr")))
    assert errors[0][0] == FIELD and "no R, G, B" in errors[0][1], errors


def test_albedo_texels_must_be_at_most_one(tmp_path):
    (tmp_path / "bright.exr").write_bytes(encode_exr(np.full((2, 2, 3), 1.5, np.float32)))
    errors = errors_of(tmp_path, textured_scene(bitmap("bright.exr")))
    assert errors[0][0] == FIELD and "in [0, 1]" in errors[0][1], errors


def test_texture_limits_name_the_field(tmp_path):
    Image.fromarray(np.zeros((8, 16, 3), np.uint8)).save(tmp_path / "wide.png")
    errors = errors_of(tmp_path, textured_scene(bitmap("wide.png")),
                       limits=Limits(max_texture_side=12))
    assert errors[0][0] == FIELD and "LUCENT_MAX_TEXTURE_SIDE" in errors[0][1], errors
    errors = errors_of(tmp_path, textured_scene(bitmap("wide.png")), limits=Limits(max_texels=100))
    assert errors[0][0] == FIELD and "LUCENT_MAX_TEXELS" in errors[0][1], errors


def test_the_texel_budget_is_shared_with_the_environment(tmp_path):
    """max_texels counts the environment's texels and every texture's together."""
    (tmp_path / "sky.pfm").write_bytes(encode_pfm(np.ones((8, 16, 3), np.float32)))
    Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(tmp_path / "t.png")
    scene = textured_scene(bitmap("t.png"), environment={"image": "sky.pfm"})
    del scene["background"]
    load(tmp_path, scene, limits=Limits(max_texels=192))
    errors = errors_of(tmp_path, scene, limits=Limits(max_texels=191))
    assert errors[0][0] == FIELD and "192 texels" in errors[0][1], errors


def test_schema_errors_name_the_texture_field(tmp_path):
    errors = errors_of(tmp_path, textured_scene({"type": "checkerboard", "scale": [1]}))
    assert errors == [("materials.m.albedo.scale", "must have exactly 2 elements, not 1")]
    errors = errors_of(tmp_path, textured_scene({"type": "marble"}))
    assert errors[0][0] == "materials.m.albedo", errors
    errors = errors_of(tmp_path, textured_scene([1.5, 0, 0]))
    assert errors == [("materials.m.albedo[0]", "must be <= 1")]


def test_http_scenes_refuse_texture_paths():
    with pytest.raises(SceneError) as info:
        load_scene(textured_scene(bitmap("t.png")))
    assert info.value.errors[0][0] == FIELD


# --- rendered -------------------------------------------------------------------------------------


def test_rendered_quad_shows_the_texture_upright(tmp_path):
    """A quad facing the camera with max_depth 1 under a white background shows its albedo: the
    image's top-left texel (red) at the quad's top-left, its bottom-right (blue) at the bottom
    right. A flipped u or v swaps them."""
    from renderer.render import render

    image = np.full((4, 4, 3), 255, np.uint8)
    image[:2, :2] = [255, 0, 0]
    image[2:, 2:] = [0, 0, 255]
    Image.fromarray(image).save(tmp_path / "corners.png")
    scene = textured_scene({"type": "bitmap", "image": "corners.png"})
    scene["camera"] = {"position": [0.5, 0.5, 1.0], "look_at": [0.5, 0.5, 0.0],
                       "fov": 2 * math.degrees(math.atan(0.25))}  # sees s, t in [0.25, 0.75]
    rgb = render(load(tmp_path, scene), threads=1)
    top_left, bottom_right = rgb[:4, :4].mean(axis=(0, 1)), rgb[-4:, -4:].mean(axis=(0, 1))
    assert top_left[0] > 0.7 and top_left[2] < 0.2, top_left
    assert bottom_right[2] > 0.7 and bottom_right[0] < 0.2, bottom_right


UNIFORM = {  # (material, the colour parameter a uniform checkerboard replaces)
    "diffuse": ({"type": "diffuse", "albedo": [0.6, 0.4, 0.2]}, "albedo"),
    "phong-diffuse": ({"type": "phong", "diffuse": [0.5, 0.3, 0.2], "specular": [0.3, 0.3, 0.3],
                       "exponent": 20}, "diffuse"),
    "phong-specular": ({"type": "phong", "diffuse": [0.5, 0.3, 0.2], "specular": [0.3, 0.3, 0.3],
                        "exponent": 20}, "specular"),
    "mirror": ({"type": "mirror", "reflectance": [0.9, 0.7, 0.5]}, "reflectance"),
    "conductor": ({"type": "conductor", "preset": "Au", "roughness": 0.2,
                   "specular": [0.9, 0.8, 0.7]}, "specular"),
    "single_scatter": ({"type": "translucent", "method": "single_scatter", "ior": 1.3,
                        "albedo": [0.9, 0.7, 0.5], "density": 2.0}, "albedo"),
    "diffuse_entry": ({"type": "translucent", "method": "diffuse_entry", "ior": 1.3,
                       "albedo": [0.9, 0.7, 0.5], "density": 2.0, "direct_light": True},
                      "albedo"),
    "backlight": ({"type": "translucent", "method": "backlight", "ior": 1.3,
                   "albedo": [0.9, 0.7, 0.5], "density": 2.0, "scale": 0.4}, "albedo"),
    "diffusion": ({"type": "translucent", "method": "diffusion", "ior": 1.3,
                   "albedo": [0.9, 0.7, 0.5], "density": 20.0}, "albedo"),
}


@pytest.mark.parametrize("name", sorted(UNIFORM))
def test_a_uniform_texture_is_the_colour_itself(name):
    """Every textured slot of every material that takes a texture: a checkerboard whose two
    colours are the material's RGB renders the very image of that RGB, bit for bit (backlight:
    its reflected share (1 − scale)·albedo and its transmitted term both follow the texture;
    diffusion: its profile's A and d, recomputed at the hit, to rounding)."""
    from renderer.render import render

    material, param = UNIFORM[name]
    scene = {
        "camera": {"position": [0, 0.5, 3], "look_at": [0, 0, 0], "fov": 40},
        "film": {"width": 16, "height": 12},
        "render": {"spp": 4, "max_depth": 4, "seed": 2},
        "background": [0.3, 0.4, 0.5],
        "materials": {"m": material, "floor": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
        "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 0.7, "material": "m"},
                    {"type": "quad", "origin": [-3, -0.7, 3], "edge1": [6, 0, 0],
                     "edge2": [0, 0, -6], "material": "floor"}],
        "lights": [{"type": "point", "position": [1, 2, -2], "intensity": [8, 8, 8]}],
    }
    plain = render(load_scene(scene), threads=1)
    rgb = material[param]
    material[param] = {"type": "checkerboard", "color0": rgb, "color1": rgb, "scale": [5, 3]}
    textured = render(load_scene(scene), threads=1)
    material[param] = rgb
    assert plain.max() > 0.0
    if name == "diffusion":  # its profile recomputed in the kernel (math.exp, not np.exp)
        np.testing.assert_allclose(textured, plain, rtol=1e-9, atol=1e-12)
    else:
        np.testing.assert_array_equal(textured, plain)


def test_translucent_textures_only_where_they_colour_a_surface():
    scene = textured_scene({"type": "checkerboard"})
    scene["materials"]["m"] = {"type": "translucent", "method": "volumetric",
                               "albedo": {"type": "checkerboard"}}
    with pytest.raises(SceneError) as info:
        load_scene(scene)
    assert info.value.errors[0][0] == "materials.m" and "volumetric" in info.value.errors[0][1]


def test_the_diffusion_profile_at_a_hit_is_the_hosts(rng):
    """A textured diffusion albedo: the kernel's A and d from the albedo at the hit
    (``profile_from_albedo``) are ``diffusion_parameters``' (the host's, for an RGB albedo)."""
    from renderer.materials.diffusion import (
        MS_ALBEDO,
        PROFILE_D,
        diffusion_parameters,
        profile_from_albedo,
    )
    from renderer.materials.translucent import ALBEDO, IOR, SIGMA_T, G

    for _ in range(50):
        albedo, sigma_t = rng.uniform(0.0, 1.0, 3), rng.uniform(0.5, 50.0, 3)
        g, ior = rng.uniform(-0.5, 0.9), rng.uniform(1.0, 1.8)
        row = np.zeros(23)
        row[ALBEDO:ALBEDO + 3], row[SIGMA_T:SIGMA_T + 3], row[G], row[IOR] = albedo, sigma_t, g, ior
        profile_from_albedo(row)
        big_a, d, _ = diffusion_parameters(albedo, sigma_t, g, ior)
        np.testing.assert_allclose(row[MS_ALBEDO:MS_ALBEDO + 3], big_a, rtol=1e-12)
        np.testing.assert_allclose(row[PROFILE_D:PROFILE_D + 3], d, rtol=1e-12)
