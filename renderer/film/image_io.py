"""Image files: write a linear HxWx3 frame buffer, read one back.

| Extension | Written as                                 | Read                                    |
|-----------|--------------------------------------------|-----------------------------------------|
| `.exr`    | OpenEXR scanline, float32 B/G/R, no compr. | any: the OpenEXR library (`openexr`)    |
| `.pfm`    | Portable Float Map "PF", little-endian     | "PF" and greyscale "Pf", either endian  |
| `.hdr`    | (not written)                              | Radiance RGBE, flat or run-length coded |
| `.npy`    | NumPy float32 HxWx3                        | HxWx3 or HxW of any real dtype          |
| `.png`    | 8-bit sRGB after exposure and tone map     | 8-bit, decoded from sRGB to linear      |

Example: `write_image("out/frame.png", rgb, exposure=0.5, tonemap="aces")`; `exposure` and
`tonemap` only change PNG output, the float formats always hold the radiance as rendered.

The EXR writer is written here in NumPy (plus zlib): the layout is small and documented
("OpenEXR File Layout", openexr.com). Reading goes through the OpenEXR library's own bindings (the
`openexr` package), since the files users bring (environment maps from Blender, Mitsuba or HDRI
sites) use PIZ, DWAA and other coders that are not worth writing again. `decode_hdr_image` reads
the three float formats a scene may name (EXR, PFM, Radiance `.hdr`) from their bytes, and
`decode_texture` a bitmap texture's (PNG of 8 or 16 bits per channel, `decode_png`; EXR, PFM).
"""

import io
import os
import secrets
import struct
import zlib
from pathlib import Path

import numpy as np
from PIL import Image

from renderer.film.tonemap import srgb_to_linear, to_srgb8

SUPPORTED_EXTENSIONS = (".exr", ".pfm", ".npy", ".png")
READ_EXTENSIONS = SUPPORTED_EXTENSIONS + (".hdr",)

# --- OpenEXR constants (OpenEXR File Layout, "Header Attributes" and "Scan Line Blocks") ---------
_EXR_MAGIC = 20000630
_EXR_VERSION = 2
_EXR_PIXEL_DTYPES = {0: np.dtype("<u4"), 1: np.dtype("<f2"), 2: np.dtype("<f4")}  # UINT HALF FLOAT
_EXR_COMPRESSIONS = ("NONE", "RLE", "ZIPS", "ZIP", "PIZ", "PXR24", "B44", "B44A", "DWAA", "DWAB")
# Scan lines stored together in one chunk, indexed like _EXR_COMPRESSIONS.
_EXR_LINES_PER_CHUNK = (1, 1, 1, 16, 32, 16, 32, 32, 32, 256)
_EXR_ZIP = 3


def write_image(
    path: str | os.PathLike, rgb: np.ndarray, *, exposure: float = 0.0, tonemap: str = "clamp"
) -> None:
    """Write a linear HxWx3 float image; the format follows the extension (case-insensitive).

    `exposure` (stops) and `tonemap` apply to `.png` only. The file appears atomically: it is
    written beside the target and renamed, so a reader never sees half a frame.
    """
    ext = _extension(path)
    rgb = _check_rgb(rgb)
    if ext == ".exr":
        data = encode_exr(rgb)
    elif ext == ".pfm":
        data = encode_pfm(rgb)
    elif ext == ".npy":
        buffer = io.BytesIO()
        np.save(buffer, np.ascontiguousarray(rgb, dtype=np.float32), allow_pickle=False)
        data = buffer.getvalue()
    else:
        buffer = io.BytesIO()
        Image.fromarray(to_srgb8(rgb, exposure, tonemap), "RGB").save(buffer, format="PNG")
        data = buffer.getvalue()
    _write_atomically(Path(path), data)


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image as linear float32 HxWx3; the format follows the extension."""
    ext = _extension(path, READ_EXTENSIONS)
    if ext == ".hdr":
        return decode_rgbe(Path(path).read_bytes(), name=str(path))
    if ext == ".exr":
        return decode_exr(Path(path).read_bytes(), name=str(path))
    if ext == ".pfm":
        return decode_pfm(Path(path).read_bytes(), name=str(path))
    if ext == ".npy":
        return _as_rgb(np.load(path, allow_pickle=False), str(path))
    with Image.open(path) as image:
        if image.mode not in ("RGB", "RGBA", "L", "LA", "P"):
            raise ValueError(f"{path}: PNG mode {image.mode} is not supported (8-bit only)")
        srgb8 = np.asarray(image.convert("RGB"))
    return srgb_to_linear(srgb8.astype(np.float32) / 255.0)


# --- OpenEXR --------------------------------------------------------------------------------------


def encode_exr(rgb: np.ndarray, *, compression: str = "NONE", pixel_type: str = "FLOAT") -> bytes:
    """Encode HxWx3 linear RGB as a single-part scanline OpenEXR file.

    `compression` is "NONE" or "ZIP" (zlib, 16 lines a chunk); `pixel_type` is "FLOAT" or "HALF".
    `write_image` always uses NONE/FLOAT: lossless and the fastest to write and read.
    """
    rgb = _check_rgb(rgb)
    if compression not in ("NONE", "ZIP"):
        raise ValueError(f"EXR compression {compression!r} cannot be written; use NONE or ZIP")
    if pixel_type not in ("FLOAT", "HALF"):
        raise ValueError(f"EXR pixel type {pixel_type!r} cannot be written; use FLOAT or HALF")
    height, width, _ = rgb.shape
    code = _EXR_COMPRESSIONS.index(compression)
    type_code = 2 if pixel_type == "FLOAT" else 1
    dtype = _EXR_PIXEL_DTYPES[type_code]

    # Header: the attributes every reader requires, alphabetical like OpenEXR's own writer.
    channels = b"".join(
        name + b"\0" + struct.pack("<iB3xii", type_code, 0, 1, 1) for name in (b"B", b"G", b"R")
    )
    window = struct.pack("<iiii", 0, 0, width - 1, height - 1)
    header = b"".join(
        [
            struct.pack("<ii", _EXR_MAGIC, _EXR_VERSION),
            _exr_attribute("channels", "chlist", channels + b"\0"),
            _exr_attribute("compression", "compression", bytes([code])),
            _exr_attribute("dataWindow", "box2i", window),
            _exr_attribute("displayWindow", "box2i", window),
            _exr_attribute("lineOrder", "lineOrder", b"\0"),  # INCREASING_Y
            _exr_attribute("pixelAspectRatio", "float", struct.pack("<f", 1.0)),
            _exr_attribute("screenWindowCenter", "v2f", struct.pack("<ff", 0.0, 0.0)),
            _exr_attribute("screenWindowWidth", "float", struct.pack("<f", 1.0)),
            b"\0",
        ]
    )

    # Pixel data: each scan line holds all of B, then all of G, then all of R (channel order).
    # Values beyond HALF's range become inf, as in OpenEXR's own float-to-half conversion.
    with np.errstate(over="ignore"):
        lines = np.ascontiguousarray(rgb[:, :, ::-1].transpose(0, 2, 1), dtype=dtype)
    lines_per_chunk = _EXR_LINES_PER_CHUNK[code]
    chunks = []
    for y in range(0, height, lines_per_chunk):
        raw = lines[y : y + lines_per_chunk].tobytes()
        data = _zip_encode(raw) if code == _EXR_ZIP else raw
        if len(data) >= len(raw):
            data = raw  # the format's rule: a chunk that does not shrink is stored as is
        chunks.append(struct.pack("<ii", y, len(data)) + data)

    # Offset table: the absolute file position of each chunk, right after the header.
    first = len(header) + 8 * len(chunks)
    offsets = np.cumsum([first] + [len(chunk) for chunk in chunks[:-1]], dtype=np.uint64)
    return header + offsets.astype("<u8").tobytes() + b"".join(chunks)


def decode_exr(data: bytes, *, name: str = "<exr>") -> np.ndarray:
    """Decode an OpenEXR file to float32 HxWx3, through the OpenEXR library (``openexr``).

    Every compression the library knows (NONE, RLE, ZIPS, ZIP, PIZ, PXR24, B44, DWAA, DWAB, …, as
    Blender, Mitsuba and HDRI sites write), scanline or tiled, pixel types UINT, HALF and FLOAT;
    of a multi-part file, the first part. Channels R, G, B are used (a luminance-only file's Y is
    copied to all three); others such as A are ignored. A file that is not OpenEXR, is truncated
    or has no colour channels raises ``ValueError`` naming ``name``.
    """
    if len(data) < 8 or struct.unpack_from("<i", data, 0)[0] != _EXR_MAGIC:
        raise ValueError(f"{name}: not an OpenEXR file (bad magic number)")
    try:
        import OpenEXR  # the maintained bindings of the reference library (PyPI ``openexr``)

        exr = OpenEXR.File(io.BytesIO(data), separate_channels=True)
        channels = {key: channel.pixels for key, channel in exr.channels().items()}
    except ImportError as exc:
        raise ValueError(f"{name}: OpenEXR files cannot be read here ({exc})") from None
    except Exception as exc:  # the library's errors (RuntimeError, ValueError): a bad file
        detail = str(exc).replace("<python_buffer>", "").strip(" :")
        raise ValueError(f"{name}: truncated or corrupt OpenEXR file ({detail})") from None
    if {"R", "G", "B"} <= channels.keys():
        planes = [channels["R"], channels["G"], channels["B"]]
    elif "Y" in channels:
        planes = [channels["Y"]] * 3
    else:
        raise ValueError(
            f"{name}: OpenEXR file has no R, G, B or Y channels (has {sorted(channels)})"
        )
    if any(plane.ndim != 2 or plane.shape != planes[0].shape for plane in planes):
        raise ValueError(f"{name}: OpenEXR colour channels of different sizes (subsampled)")
    return np.stack(planes, axis=-1).astype(np.float32)


# Pixel type of each AOV layer in a multi-layer EXR: half where 3 decimal digits are plenty
# (albedo and normal, in [0, 1] and [-1, 1]), float where values span many decades or count
EXR_LAYER_TYPES = {"albedo": "HALF", "normal": "HALF", "depth": "FLOAT", "variance": "FLOAT",
                   "spp": "FLOAT", "noisy": "FLOAT"}
# Layers beside the AOVs: ``noisy``, the undenoised image of a denoised frame (the farm's)
EXR_EXTRA_CHANNELS = {"noisy": ("R", "G", "B")}


def encode_exr_layers(rgb: np.ndarray, layers: dict[str, np.ndarray]) -> bytes:
    """Encode a beauty image (channels R, G, B, float) and named AOV layers as one multi-layer
    OpenEXR file through the OpenEXR library (``openexr``), ZIP-compressed.

    Each layer is (h, w, C) with C its channels in ``renderer.film.aov.AOV_CHANNELS`` (``albedo``
    → ``albedo.R/G/B``, ``normal`` → ``normal.X/Y/Z``, ``depth`` → ``depth.Z``, ``variance`` →
    ``variance.R/G/B``, ``spp`` → ``spp.Y``) or ``EXR_EXTRA_CHANNELS`` (``noisy`` →
    ``noisy.R/G/B``), written as half or float (``EXR_LAYER_TYPES``).
    """
    import OpenEXR

    from renderer.film.aov import AOV_CHANNELS

    rgb = _check_rgb(rgb)
    h, w, _ = rgb.shape
    channels = {c: np.ascontiguousarray(rgb[..., i], np.float32) for i, c in enumerate("RGB")}
    known = {**AOV_CHANNELS, **EXR_EXTRA_CHANNELS}
    for name, pixels in layers.items():
        if name not in known:
            raise ValueError(f"unknown AOV layer {name!r} (known: {', '.join(known)})")
        names = known[name]
        pixels = np.asarray(pixels)
        if pixels.shape != (h, w, len(names)):
            raise ValueError(f"AOV layer {name!r} has shape {pixels.shape}, expected "
                             f"{(h, w, len(names))}")
        dtype = np.float16 if EXR_LAYER_TYPES[name] == "HALF" else np.float32
        with np.errstate(over="ignore"):
            for i, c in enumerate(names):
                channels[f"{name}.{c}"] = np.ascontiguousarray(pixels[..., i], dtype)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    buffer = io.BytesIO()
    OpenEXR.File(header, channels).write(buffer)
    return buffer.getvalue()


def write_exr_layers(path: str | os.PathLike, rgb: np.ndarray,
                     layers: dict[str, np.ndarray]) -> None:
    """Write ``encode_exr_layers``'s file atomically (as ``write_image``)."""
    if _extension(path) != ".exr":
        raise ValueError(f"{path}: AOV layers are written to OpenEXR files only (.exr)")
    _write_atomically(Path(path), encode_exr_layers(rgb, layers))


def _exr_attribute(name: str, type_name: str, value: bytes) -> bytes:
    size = struct.pack("<i", len(value))
    return name.encode() + b"\0" + type_name.encode() + b"\0" + size + value


def _zip_encode(raw: bytes) -> bytes:
    """OpenEXR ZIP: split even/odd bytes, delta-code them, deflate (ImfZip.cpp)."""
    t = np.frombuffer(raw, np.uint8)
    # Bytes of the same significance end up next to each other, which deflate rewards.
    t = np.concatenate([t[0::2], t[1::2]])
    d = t.copy()
    d[1:] = t[1:] - t[:-1] + np.uint8(128)  # uint8 arithmetic wraps mod 256, as in the C code
    return zlib.compress(d.tobytes())


# --- Portable Float Map ---------------------------------------------------------------------------


def encode_pfm(rgb: np.ndarray) -> bytes:
    """Colour PFM: header "PF", negative scale for little-endian data, rows bottom to top."""
    rgb = _check_rgb(rgb)
    height, width, _ = rgb.shape
    header = f"PF\n{width} {height}\n-1.0\n".encode("ascii")
    return header + np.ascontiguousarray(rgb[::-1], dtype="<f4").tobytes()


def decode_pfm(data: bytes, *, name: str = "<pfm>") -> np.ndarray:
    # Header: three whitespace-separated tokens (kind, "width height", scale), then exactly one
    # whitespace byte before the raster, which may itself start with a whitespace-like byte.
    tokens = []
    pos = 0
    for _ in range(4):
        while pos < len(data) and data[pos : pos + 1].isspace():
            pos += 1
        start = pos
        while pos < len(data) and not data[pos : pos + 1].isspace():
            pos += 1
        tokens.append(data[start:pos])
    pos += 1
    kind = tokens[0]
    if kind not in (b"PF", b"Pf"):
        raise ValueError(f"{name}: not a PFM file (header {kind[:8]!r})")
    try:
        width, height, scale = int(tokens[1]), int(tokens[2]), float(tokens[3])
    except ValueError:
        raise ValueError(f"{name}: corrupt PFM header") from None
    n_channels = 3 if kind == b"PF" else 1
    dtype = np.dtype("<f4" if scale < 0 else ">f4")
    count = width * height * n_channels
    if width <= 0 or height <= 0 or pos + 4 * count > len(data):
        raise ValueError(f"{name}: PFM raster is truncated or its size is invalid")
    pixels = np.frombuffer(data, dtype, count, pos).reshape(height, width, n_channels)
    rgb = pixels[::-1].astype(np.float32)
    return np.repeat(rgb, 3, axis=2) if n_channels == 1 else rgb


# --- Radiance RGBE (.hdr) -------------------------------------------------------------------------


def decode_rgbe(data: bytes, *, name: str = "<hdr>") -> np.ndarray:
    """Decode a Radiance picture (``.hdr``, ``#?RADIANCE`` / ``#?RGBE``) to float32 HxWx3.

    The header is text lines up to a blank one (``FORMAT=32-bit_rle_rgbe``; an ``EXPOSURE`` is
    divided out, as Radiance's own readers do), then the resolution line, of which the standard
    orientation ``-Y H +X W`` (rows top to bottom, left to right) is read. Scan lines are flat
    RGBE quadruples or the run-length coding of Greg Ward's writer (each line opens 2 2 hi lo,
    then each of the four components in runs: a count > 128 repeats one byte count − 128 times,
    else count literal bytes). A texel is (r, g, b)·2^(e − 136), and 0 where e = 0
    (Ward, "Real Pixels", Graphics Gems II).
    """
    if not (data.startswith(b"#?RADIANCE") or data.startswith(b"#?RGBE")):
        raise ValueError(f"{name}: not a Radiance HDR file (no #?RADIANCE signature)")
    end = data.find(b"\n\n")
    if end < 0:
        raise ValueError(f"{name}: truncated Radiance HDR header")
    exposure = 1.0
    for line in data[:end].split(b"\n")[1:]:
        if line.startswith(b"FORMAT=") and line.strip() != b"FORMAT=32-bit_rle_rgbe":
            fmt = line[7:].strip().decode("latin-1")
            raise ValueError(
                f"{name}: Radiance HDR format {fmt!r} is not supported (32-bit_rle_rgbe is)"
            )
        if line.startswith(b"EXPOSURE="):
            try:
                exposure *= float(line[9:])
            except ValueError:
                raise ValueError(f"{name}: corrupt Radiance HDR EXPOSURE line") from None
    size_end = data.find(b"\n", end + 2)
    tokens = data[end + 2 : size_end if size_end >= 0 else len(data)].split()
    if len(tokens) != 4 or tokens[0] != b"-Y" or tokens[2] != b"+X":
        raise ValueError(
            f"{name}: Radiance HDR resolution line {b' '.join(tokens)[:40]!r} is not supported "
            "(the standard orientation -Y H +X W is)"
        )
    try:
        height, width = int(tokens[1]), int(tokens[3])
    except ValueError:
        raise ValueError(f"{name}: corrupt Radiance HDR resolution line") from None
    if height <= 0 or width <= 0 or size_end < 0:
        raise ValueError(f"{name}: Radiance HDR image of invalid size {width}x{height}")
    if not exposure > 0.0:
        raise ValueError(f"{name}: Radiance HDR EXPOSURE must be > 0")
    raw = np.frombuffer(data, np.uint8, offset=size_end + 1)
    rgbe = np.empty((height, width, 4), np.uint8)
    pos = 0
    truncated = f"{name}: truncated Radiance HDR pixel data"
    for y in range(height):
        head = raw[pos : pos + 4]
        rle = (8 <= width < 32768 and len(head) == 4 and head[0] == 2 and head[1] == 2
               and head[2] < 128)
        if not rle:
            # Flat: width quadruples
            if pos + 4 * width > len(raw):
                raise ValueError(truncated)
            rgbe[y] = raw[pos : pos + 4 * width].reshape(width, 4)
            pos += 4 * width
            continue
        if (int(head[2]) << 8 | int(head[3])) != width:
            raise ValueError(f"{name}: corrupt Radiance HDR scan line {y} (wrong length)")
        pos += 4
        for c in range(4):
            x = 0
            while x < width:
                if pos >= len(raw):
                    raise ValueError(truncated)
                count = int(raw[pos])
                if count > 128:
                    count -= 128
                    if x + count > width or pos + 1 >= len(raw):
                        raise ValueError(f"{name}: corrupt Radiance HDR scan line {y}")
                    rgbe[y, x : x + count, c] = raw[pos + 1]
                    pos += 2
                else:
                    if count == 0 or x + count > width or pos + 1 + count > len(raw):
                        raise ValueError(f"{name}: corrupt Radiance HDR scan line {y}")
                    rgbe[y, x : x + count, c] = raw[pos + 1 : pos + 1 + count]
                    pos += 1 + count
                x += count
    e = rgbe[:, :, 3].astype(np.int32)
    scale = np.where(e > 0, np.ldexp(1.0, e - 136), 0.0) / exposure
    return (rgbe[:, :, :3].astype(np.float64) * scale[:, :, None]).astype(np.float32)


def decode_hdr_image(data: bytes, kind: str, *, name: str) -> np.ndarray:
    """A float image from its bytes: ``kind`` is ``.exr``, ``.pfm`` or ``.hdr``
    (``renderer.scene.files.sniff``); float32 HxWx3, or ``ValueError`` naming ``name``."""
    if kind == ".exr":
        return decode_exr(data, name=name)
    if kind == ".pfm":
        return decode_pfm(data, name=name)
    if kind == ".hdr":
        return decode_rgbe(data, name=name)
    raise ValueError(f"{name}: not a float image (EXR, PFM or Radiance HDR)")


# --- PNG textures (8 and 16 bits per channel) ----------------------------------------------------

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_CHANNELS = {0: 1, 2: 3, 4: 2, 6: 4}  # colour type -> samples per pixel (grey, RGB, GA, RGBA)


def decode_png(data: bytes, *, name: str = "<png>") -> np.ndarray:
    """The encoded values of a PNG, float32 HxWx3 in [0, 1] (not linearized): 8-bit files of any
    colour type through Pillow, 16-bit ones here, which Pillow would cut to 8 bits (PNG
    specification, W3C 2003: chunks, zlib stream, per-row filters). Grey is copied to all three
    channels, alpha dropped. A truncated or corrupt file raises ``ValueError`` naming ``name``."""
    if not data.startswith(_PNG_SIGNATURE):
        raise ValueError(f"{name}: not a PNG file (bad signature)")
    if len(data) < 33 or data[12:16] != b"IHDR":
        raise ValueError(f"{name}: truncated PNG file (no IHDR chunk)")
    width, height, depth, colour, _, _, interlace = struct.unpack(">IIBBBBB", data[16:29])
    if depth != 16:
        try:
            with Image.open(io.BytesIO(data)) as image:
                rgb = np.asarray(image.convert("RGB"))
        except Exception as exc:  # Pillow's errors (OSError, SyntaxError, ...): a bad file
            raise ValueError(f"{name}: truncated or corrupt PNG file ({exc})") from None
        return rgb.astype(np.float32) / np.float32(255.0)
    if colour not in _PNG_CHANNELS or interlace != 0 or width == 0 or height == 0:
        raise ValueError(f"{name}: 16-bit PNG of colour type {colour}"
                         f"{', interlaced' if interlace else ''} is not supported")
    idat, pos = [], 8
    while pos + 8 <= len(data):
        length, kind = struct.unpack_from(">I4s", data, pos)
        if kind == b"IDAT":
            idat.append(data[pos + 8:pos + 8 + length])
        if kind == b"IEND":
            break
        pos += 12 + length
    channels = _PNG_CHANNELS[colour]
    stride = 2 * channels * width
    try:
        raw = zlib.decompress(b"".join(idat))
    except zlib.error as exc:
        raise ValueError(f"{name}: truncated or corrupt PNG file ({exc})") from None
    if len(raw) < height * (stride + 1):
        raise ValueError(f"{name}: truncated PNG file ({len(raw)} bytes of pixel data for "
                         f"{height * (stride + 1)})")
    rows = np.frombuffer(raw, np.uint8, height * (stride + 1)).reshape(height, stride + 1)
    if (rows[:, 0] > 4).any():
        raise ValueError(f"{name}: corrupt PNG file (unknown row filter)")
    out = np.empty((height, stride), np.uint8)
    _png_unfilter(rows, 2 * channels, out)
    values = out.view(">u2").reshape(height, width, channels).astype(np.float32) / 65535.0
    if channels <= 2:
        return np.repeat(values[:, :, :1], 3, axis=2)
    return np.ascontiguousarray(values[:, :, :3])


def _png_unfilter(rows, bpp, out):
    from renderer.jit import kernel  # lazily: numba only for the files that need it

    global _png_unfilter_kernel
    if _png_unfilter_kernel is None:
        _png_unfilter_kernel = kernel(_unfilter)
    _png_unfilter_kernel(rows, bpp, out)


_png_unfilter_kernel = None


def _unfilter(rows, bpp, out):
    """Undo PNG's per-row filters (None, Sub, Up, Average, Paeth; PNG specification, 9.2)."""
    height, width = out.shape
    for y in range(height):
        f = rows[y, 0]
        for x in range(width):
            raw = np.int32(rows[y, x + 1])
            a = np.int32(out[y, x - bpp]) if x >= bpp else np.int32(0)
            b = np.int32(out[y - 1, x]) if y > 0 else np.int32(0)
            c = np.int32(out[y - 1, x - bpp]) if (x >= bpp and y > 0) else np.int32(0)
            if f == 1:
                raw += a
            elif f == 2:
                raw += b
            elif f == 3:
                raw += (a + b) // 2
            elif f == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                raw += a if (pa <= pb and pa <= pc) else (b if pb <= pc else c)
            out[y, x] = raw & 0xFF


def decode_texture(data: bytes, kind: str, *, srgb: bool | None, name: str) -> np.ndarray:
    """A texture's linear texels, float32 HxWx3 (row 0 at the top), from its bytes: ``kind``
    ``.png`` (sRGB-decoded unless ``srgb`` is False), ``.exr`` or ``.pfm`` (linear unless ``srgb``
    is True); ``ValueError`` naming ``name`` for a file that cannot be read."""
    if kind == ".png":
        encoded = decode_png(data, name=name)
        return srgb_to_linear(encoded).astype(np.float32) if srgb in (None, True) else encoded
    if kind in (".exr", ".pfm"):
        rgb = decode_exr(data, name=name) if kind == ".exr" else decode_pfm(data, name=name)
        return srgb_to_linear(np.clip(rgb, 0.0, None)).astype(np.float32) if srgb else rgb
    raise ValueError(f"{name}: not a texture image (PNG, EXR or PFM)")


# --- helpers --------------------------------------------------------------------------------------


def _extension(path: str | os.PathLike, supported: tuple[str, ...] = SUPPORTED_EXTENSIONS) -> str:
    ext = Path(path).suffix.lower()
    if ext not in supported:
        raise ValueError(
            f"{path}: unsupported image extension {ext or '(none)'!r}; "
            f"supported: {', '.join(supported)}"
        )
    return ext


def _check_rgb(rgb: np.ndarray) -> np.ndarray:
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.shape[0] == 0 or rgb.shape[1] == 0:
        raise ValueError(f"expected a non-empty HxWx3 image, got shape {rgb.shape}")
    if not (np.issubdtype(rgb.dtype, np.floating) or np.issubdtype(rgb.dtype, np.integer)):
        raise ValueError(f"expected a real-valued image, got dtype {rgb.dtype}")
    return rgb


def _as_rgb(array: np.ndarray, name: str) -> np.ndarray:
    if array.ndim == 2:
        array = array[:, :, None].repeat(3, axis=2)
    if array.ndim != 3 or array.shape[2] != 3:
        raise ValueError(f"{name}: expected an HxWx3 or HxW array, got shape {array.shape}")
    if not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        raise ValueError(f"{name}: expected a real-valued array, got dtype {array.dtype}")
    return array.astype(np.float32)


def _write_atomically(path: Path, data: bytes) -> None:
    # A unique name beside the target keeps the final rename on one file system; open(..., "xb")
    # rather than mkstemp so that the file gets the usual umask permissions, not 0600.
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    try:
        with open(tmp, "xb") as file:
            file.write(data)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
