"""Image files and tone mapping: round trips, outside readers, the sRGB curve at known points."""

import io

import numpy as np
import pytest

from renderer.film import image_io
from renderer.film.image_io import read_image, write_image
from renderer.film.tonemap import linear_to_srgb, srgb_to_linear, to_srgb8


@pytest.fixture
def hdr_image() -> np.ndarray:
    """A small non-square float32 image with negatives, highlights and a non-trivial layout."""
    rng = np.random.default_rng(7)
    rgb = rng.lognormal(mean=-1.0, sigma=2.0, size=(37, 53, 3)).astype(np.float32)
    rgb[0, 0] = (-0.25, 0.0, 65504.0 * 4)  # a negative and a value beyond half range
    return rgb


@pytest.fixture
def mitsuba():
    mi = pytest.importorskip("mitsuba", reason="the Mitsuba 3 extra is not installed")
    mi.set_variant("scalar_rgb")
    return mi


def as_stored(rgb: np.ndarray, pixel_type: str) -> np.ndarray:
    """What an EXR of this pixel type holds: HALF rounds, and overflows to inf like OpenEXR."""
    if pixel_type == "FLOAT":
        return rgb
    with np.errstate(over="ignore"):
        return rgb.astype(np.float16)


def bits(a: np.ndarray) -> np.ndarray:
    """Bit patterns, so that equality is bit-exact (signed zeros, NaN payloads included)."""
    return np.ascontiguousarray(a, dtype=np.float32).view(np.uint32)


# --- round trips ----------------------------------------------------------------------------------


@pytest.mark.parametrize("ext", [".exr", ".pfm", ".npy", ".EXR", ".Pfm"])
def test_float_formats_round_trip_bit_exact(tmp_path, hdr_image, ext):
    hdr_image[1, 2] = (np.inf, -np.inf, -0.0)
    path = tmp_path / f"frame{ext}"
    write_image(path, hdr_image)
    back = read_image(path)
    assert back.dtype == np.float32 and back.shape == hdr_image.shape
    assert np.array_equal(bits(back), bits(hdr_image))


def test_float64_input_is_stored_as_float32(tmp_path, hdr_image):
    write_image(tmp_path / "frame.exr", hdr_image.astype(np.float64))
    assert np.array_equal(bits(read_image(tmp_path / "frame.exr")), bits(hdr_image))


def test_exposure_and_tonemap_leave_float_formats_alone(tmp_path, hdr_image):
    write_image(tmp_path / "a.exr", hdr_image, exposure=3.0, tonemap="aces")
    assert np.array_equal(bits(read_image(tmp_path / "a.exr")), bits(hdr_image))


@pytest.mark.parametrize("compression", ["NONE", "ZIP"])
@pytest.mark.parametrize("pixel_type", ["FLOAT", "HALF"])
def test_exr_codec_round_trip(tmp_path, hdr_image, compression, pixel_type):
    data = image_io.encode_exr(hdr_image, compression=compression, pixel_type=pixel_type)
    expected = as_stored(hdr_image, pixel_type)
    assert np.array_equal(bits(image_io.decode_exr(data)), bits(expected))


def test_zip_exr_really_compresses_a_smooth_image():
    # Guards the ZIP path itself: noise is stored raw (the format's fallback), a ramp is not.
    ramp = np.linspace(0.0, 1.0, 64 * 64 * 3, dtype=np.float32).reshape(64, 64, 3)
    data = image_io.encode_exr(ramp, compression="ZIP")
    assert len(data) < ramp.nbytes / 2
    assert np.array_equal(image_io.decode_exr(data), ramp)


# --- outside readers and writers (Mitsuba 3) ------------------------------------------------------


@pytest.mark.mitsuba
@pytest.mark.parametrize("compression", ["NONE", "ZIP"])
@pytest.mark.parametrize("pixel_type", ["FLOAT", "HALF"])
def test_mitsuba_reads_our_exr(tmp_path, mitsuba, hdr_image, compression, pixel_type):
    path = tmp_path / "ours.exr"
    path.write_bytes(image_io.encode_exr(hdr_image, compression=compression, pixel_type=pixel_type))
    theirs = np.array(mitsuba.Bitmap(str(path))).astype(np.float32)
    expected = as_stored(hdr_image, pixel_type)
    assert np.array_equal(bits(theirs), bits(expected))


@pytest.mark.mitsuba
def test_mitsuba_reads_write_image_exr(tmp_path, mitsuba, hdr_image):
    write_image(tmp_path / "ours.exr", hdr_image)
    theirs = np.array(mitsuba.Bitmap(str(tmp_path / "ours.exr")))
    assert theirs.dtype == np.float32
    assert np.array_equal(bits(theirs), bits(hdr_image))


@pytest.mark.mitsuba
def test_we_read_mitsuba_exr_stored_raw(tmp_path, mitsuba):
    # Mitsuba always writes PIZ. A chunk that PIZ cannot shrink is stored raw (as OpenEXR requires
    # of every compressor), and a 3x4 image of random floats is far too small for PIZ's tables to
    # pay off, so this exercises Mitsuba's header and chunk layout without a PIZ decoder.
    rgb = np.random.default_rng(3).random((3, 4, 3)).astype(np.float32)
    mitsuba.Bitmap(rgb).write(str(tmp_path / "theirs.exr"))
    assert np.array_equal(bits(read_image(tmp_path / "theirs.exr")), bits(rgb))


@pytest.mark.mitsuba
def test_we_read_mitsuba_exr_of_a_real_image(tmp_path, mitsuba, hdr_image):
    # Mitsuba writes EXR as PIZ (Huffman + wavelet), which a smooth image really compresses with:
    # read through the OpenEXR library, bit-exact.
    ramp = np.linspace(0.0, 1.0, 64 * 64 * 3, dtype=np.float32).reshape(64, 64, 3)
    for name, rgb in (("ramp", ramp), ("hdr", hdr_image)):
        path = tmp_path / f"{name}.exr"
        mitsuba.Bitmap(rgb).write(str(path))
        assert np.array_equal(bits(read_image(path)), bits(rgb)), name
    assert (tmp_path / "ramp.exr").stat().st_size < 0.6 * ramp.nbytes  # really PIZ-coded


@pytest.mark.parametrize("compression", ["PIZ", "ZIP", "ZIPS", "RLE", "PXR24", "DWAA", "DWAB"])
def test_exr_of_every_common_compression(compression, hdr_image):
    # As Blender and HDRI sites write them (the OpenEXR library's own writer): lossless ones
    # bit-exact on noise, PXR24 (24-bit floats) and the DWA ones (lossy, on HALF) close on a
    # smooth sky-like gradient (DWA is a perceptual DCT coder: noise is what it throws away).
    import OpenEXR

    y, x = np.mgrid[0:37, 0:53]
    smooth = np.exp(np.stack([x / 20.0, y / 15.0, (x + y) / 30.0], axis=-1)).astype(np.float32)
    lossless = compression in ("PIZ", "ZIP", "ZIPS", "RLE")
    rgb = np.abs(hdr_image).clip(0.0, 60000.0) if lossless else smooth
    lossless = compression in ("PIZ", "ZIP", "ZIPS", "RLE")
    pixels = rgb if lossless or compression == "PXR24" else rgb.astype(np.float16)
    header = {"compression": getattr(OpenEXR, f"{compression}_COMPRESSION"),
              "type": OpenEXR.scanlineimage}
    buffer = io.BytesIO()
    OpenEXR.File(header, {"RGB": pixels}).write(buffer)
    back = image_io.decode_exr(buffer.getvalue(), name="env.exr")
    assert back.shape == rgb.shape and back.dtype == np.float32
    if lossless:
        assert np.array_equal(bits(back), bits(rgb))
    else:
        assert np.allclose(back, pixels.astype(np.float32), rtol=0.02)


def test_tiled_and_luminance_exr(hdr_image):
    import OpenEXR

    grey = np.abs(hdr_image[:, :, 0])
    buffer = io.BytesIO()
    tiles = OpenEXR.TileDescription()
    tiles.xSize = tiles.ySize = 16
    header = {"type": OpenEXR.tiledimage, "tiles": tiles}
    OpenEXR.File(header, {"Y": grey}).write(buffer)
    back = image_io.decode_exr(buffer.getvalue())
    assert np.array_equal(back, np.stack([grey] * 3, axis=-1))


def test_exr_without_colour_channels_is_refused_by_name():
    import OpenEXR

    buffer = io.BytesIO()
    OpenEXR.File({}, {"Z": np.ones((4, 4), np.float32)}).write(buffer)
    with pytest.raises(ValueError, match=r"depth\.exr: .*no R, G, B or Y channels.*Z"):
        image_io.decode_exr(buffer.getvalue(), name="depth.exr")


# --- Radiance RGBE (.hdr) -------------------------------------------------------------------------


def rgbe_flat(rgb: np.ndarray) -> bytes:
    """A flat (not run-length coded) Radiance file, by Ward's frexp rule."""
    m, e = np.frexp(rgb.max(axis=2))
    scale = np.where(rgb.max(axis=2) > 1e-32, m * 256.0 / rgb.max(axis=2), 0.0)
    quads = np.zeros(rgb.shape[:2] + (4,), np.uint8)
    quads[:, :, :3] = (rgb * scale[:, :, None]).astype(np.uint8)
    quads[:, :, 3] = np.where(rgb.max(axis=2) > 1e-32, e + 128, 0)
    h, w, _ = rgb.shape
    return f"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {h} +X {w}\n".encode() + quads.tobytes()


def test_rgbe_flat_decodes_within_its_precision():
    rgb = np.random.default_rng(5).lognormal(-1.0, 2.0, (6, 5, 3)).astype(np.float32)
    back = image_io.decode_rgbe(rgbe_flat(rgb))
    # 8-bit mantissas shared by the pixel: error ≤ 1/256 of the pixel's largest channel
    assert np.all(np.abs(back - rgb) <= rgb.max(axis=2, keepdims=True) / 128.0)
    assert np.argmax(back[0, :, 0]) == np.argmax(rgb[0, :, 0])  # rows top to bottom


@pytest.mark.mitsuba
def test_rgbe_run_length_coded_agrees_with_mitsuba(tmp_path, mitsuba, hdr_image):
    # Mitsuba writes run-length coded scan lines; both readers must give the same floats
    rgb = np.abs(hdr_image)
    rgb[:, 10:30] = 0.5  # long runs
    mitsuba.Bitmap(rgb).write(str(tmp_path / "theirs.hdr"))
    data = (tmp_path / "theirs.hdr").read_bytes()
    assert data[data.index(b"+X") :].split(b"\n", 1)[1][:2] == b"\x02\x02"  # really RLE
    theirs = np.array(mitsuba.Bitmap(str(tmp_path / "theirs.hdr")))
    assert np.array_equal(read_image(tmp_path / "theirs.hdr"), theirs)


def test_rgbe_bad_files_are_refused_by_name():
    rgb = np.ones((4, 9, 3), np.float32)
    good = rgbe_flat(rgb)
    with pytest.raises(ValueError, match="sky.hdr: truncated"):
        image_io.decode_rgbe(good[:-7], name="sky.hdr")
    with pytest.raises(ValueError, match="sky.hdr: not a Radiance"):
        image_io.decode_rgbe(b"P6\n" + good, name="sky.hdr")
    with pytest.raises(ValueError, match="sky.hdr: .*orientation"):
        image_io.decode_rgbe(good.replace(b"-Y 4 +X 9", b"+Y 4 +X 9"), name="sky.hdr")


def test_decode_hdr_image_by_kind(hdr_image):
    rgb = np.abs(hdr_image)
    assert np.array_equal(image_io.decode_hdr_image(image_io.encode_exr(rgb), ".exr", name="a"),
                          rgb)
    assert np.array_equal(image_io.decode_hdr_image(image_io.encode_pfm(rgb), ".pfm", name="a"),
                          rgb)
    with pytest.raises(ValueError, match="a: not a float image"):
        image_io.decode_hdr_image(b"\x89PNG", ".png", name="a")


@pytest.mark.mitsuba
def test_pfm_agrees_with_mitsuba_both_ways(tmp_path, mitsuba, hdr_image):
    write_image(tmp_path / "ours.pfm", hdr_image)
    assert np.array_equal(np.array(mitsuba.Bitmap(str(tmp_path / "ours.pfm"))), hdr_image)
    mitsuba.Bitmap(hdr_image).write(str(tmp_path / "theirs.pfm"))
    assert np.array_equal(bits(read_image(tmp_path / "theirs.pfm")), bits(hdr_image))


@pytest.mark.mitsuba
def test_png_agrees_with_mitsuba_decoder(tmp_path, mitsuba, hdr_image):
    write_image(tmp_path / "ours.png", hdr_image)
    theirs = np.array(mitsuba.Bitmap(str(tmp_path / "ours.png")))
    assert np.array_equal(theirs, to_srgb8(hdr_image))


# --- PFM layout -----------------------------------------------------------------------------------


def test_pfm_layout_rows_bottom_to_top(tmp_path):
    # Row 0 of the array is the top of the image; PFM stores the bottom row first.
    rgb = np.zeros((2, 3, 3), np.float32)
    rgb[0] = 1.0  # top row white
    write_image(tmp_path / "a.pfm", rgb)
    data = (tmp_path / "a.pfm").read_bytes()
    assert data.startswith(b"PF\n3 2\n-1.0\n")
    raster = np.frombuffer(data[len(b"PF\n3 2\n-1.0\n") :], "<f4").reshape(2, 3, 3)
    assert (raster[0] == 0.0).all() and (raster[1] == 1.0).all()
    assert np.array_equal(read_image(tmp_path / "a.pfm"), rgb)


def test_pfm_big_endian_and_greyscale(tmp_path):
    grey = np.arange(6, dtype=np.float32).reshape(2, 3)
    (tmp_path / "g.pfm").write_bytes(b"Pf\n3 2\n1.0\n" + grey[::-1].astype(">f4").tobytes())
    back = read_image(tmp_path / "g.pfm")
    assert back.shape == (2, 3, 3)
    assert np.array_equal(back, np.repeat(grey[:, :, None], 3, axis=2))


# --- sRGB and tone mapping ------------------------------------------------------------------------


def test_srgb_oetf_known_points():
    assert to_srgb8(np.zeros((1, 1, 3)))[0, 0, 0] == 0
    assert to_srgb8(np.ones((1, 1, 3)))[0, 0, 0] == 255
    # 1.055 * 0.5 ** (1 / 2.4) - 0.055 = 0.7354 -> 187.5 -> 188
    assert to_srgb8(np.full((1, 1, 3), 0.5))[0, 0, 0] == 188
    # The break point: both pieces meet at 0.0404500 (12.92 * 0.0031308) -> code 10.
    assert linear_to_srgb(0.0031308) == pytest.approx(12.92 * 0.0031308, rel=1e-12)
    assert linear_to_srgb(0.0031308 + 1e-9) == pytest.approx(12.92 * 0.0031308, rel=1e-6)
    assert to_srgb8(np.full((1, 1, 3), 0.0031308))[0, 0, 0] == 10
    # Each side of the break uses its own piece.
    assert linear_to_srgb(0.003) == pytest.approx(12.92 * 0.003, rel=1e-12)
    assert linear_to_srgb(0.2) == pytest.approx(1.055 * 0.2 ** (1 / 2.4) - 0.055, rel=1e-12)


def test_srgb_inverse():
    x = np.linspace(0.0, 1.0, 1001)
    assert np.allclose(srgb_to_linear(linear_to_srgb(x)), x, rtol=0, atol=1e-12)


def test_exposure_one_stop_doubles():
    x = np.linspace(0.0, 0.5, 300).reshape(10, 10, 3)
    assert np.array_equal(to_srgb8(x, exposure=1.0), to_srgb8(2.0 * x))
    assert np.array_equal(to_srgb8(x, exposure=-1.0), to_srgb8(0.5 * x))


@pytest.mark.parametrize("tonemap", ["clamp", "reinhard", "aces"])
def test_non_finite_pixels_become_black(tonemap):
    rgb = np.full((1, 4, 3), 0.5, np.float32)
    rgb[0, 1:] = [[np.nan] * 3, [np.inf] * 3, [-np.inf] * 3]
    out = to_srgb8(rgb, tonemap=tonemap)
    assert out[0, 0, 0] > 0
    assert (out[0, 1:] == 0).all()


def test_tonemap_curves():
    x = np.array([0.0, 0.18, 1.0, 4.0, 1e3, 1e30], np.float32).repeat(3).reshape(1, -1, 3)
    clamp = to_srgb8(x, tonemap="clamp")[0, :, 0]
    reinhard = to_srgb8(x, tonemap="reinhard")[0, :, 0]
    aces = to_srgb8(x, tonemap="aces")[0, :, 0]
    assert list(clamp[2:]) == [255] * 4
    # Reinhard: 1 -> 0.5 linear -> 188; 4 -> 0.8 -> round(255 * 0.9063) = 231.
    assert reinhard[2] == 188 and reinhard[3] == 231
    # Narkowicz's fit is pre-exposed so that 1.0 lands near 0.8 linear (sRGB code ~231).
    assert abs(int(aces[2]) - 231) <= 2
    for curve in (reinhard, aces):
        assert curve[0] == 0 and np.all(np.diff(curve.astype(int)) >= 0) and curve[-1] == 255
    with pytest.raises(ValueError, match="reinhard"):
        to_srgb8(x, tonemap="filmic")


def test_png_round_trip(tmp_path):
    rng = np.random.default_rng(11)
    rgb = rng.random((20, 30, 3)).astype(np.float32)
    write_image(tmp_path / "a.png", rgb)
    back = read_image(tmp_path / "a.png")
    assert back.dtype == np.float32 and back.shape == rgb.shape
    # Decoding inverts the encoding: the same 8-bit codes come out again ...
    assert np.array_equal(to_srgb8(back), to_srgb8(rgb))
    # ... so in the encoded domain the only error is quantization, at most half a code.
    error = np.abs(linear_to_srgb(back) - linear_to_srgb(rgb)) * 255.0
    assert error.max() <= 0.5 + 1e-4


def test_png_applies_exposure_and_tonemap(tmp_path):
    rgb = np.full((2, 2, 3), 0.25, np.float32)
    write_image(tmp_path / "a.png", rgb, exposure=1.0, tonemap="reinhard")
    back = read_image(tmp_path / "a.png")
    # 0.25 * 2 = 0.5 -> Reinhard 1/3 -> stored as an 8-bit sRGB code -> within half a code.
    assert np.allclose(linear_to_srgb(back), linear_to_srgb(1.0 / 3.0), atol=0.5 / 255 + 1e-6)


# --- errors ---------------------------------------------------------------------------------------


def test_unknown_extension_names_the_supported_ones(tmp_path, hdr_image):
    with pytest.raises(ValueError, match=r"\.exr.*\.pfm.*\.npy.*\.png"):
        write_image(tmp_path / "frame.tiff", hdr_image)
    with pytest.raises(ValueError, match="supported"):
        read_image(tmp_path / "frame")


def test_bad_shape_is_refused(tmp_path):
    with pytest.raises(ValueError, match="HxWx3"):
        write_image(tmp_path / "a.exr", np.zeros((4, 4, 4), np.float32))


def test_corrupt_exr_is_refused():
    data = image_io.encode_exr(np.ones((4, 4, 3), np.float32))
    with pytest.raises(ValueError, match="OpenEXR"):
        image_io.decode_exr(b"\0" + data[1:])
    with pytest.raises(ValueError, match="OpenEXR"):
        image_io.decode_exr(data[:-10])


def test_no_temporary_files_left_behind(tmp_path, hdr_image):
    for ext in (".exr", ".pfm", ".npy", ".png"):
        write_image(tmp_path / f"a{ext}", hdr_image)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.exr", "a.npy", "a.pfm", "a.png"]
