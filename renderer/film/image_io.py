"""Image files: write a linear HxWx3 frame buffer, read one back.

| Extension | Written as                                 | Read                                    |
|-----------|--------------------------------------------|-----------------------------------------|
| `.exr`    | OpenEXR scanline, float32 B/G/R, no compr. | FLOAT/HALF/UINT scanline; NONE/ZIP/ZIPS |
| `.pfm`    | Portable Float Map "PF", little-endian     | "PF" and greyscale "Pf", either endian  |
| `.npy`    | NumPy float32 HxWx3                        | HxWx3 or HxW of any real dtype          |
| `.png`    | 8-bit sRGB after exposure and tone map     | 8-bit, decoded from sRGB to linear      |

Example: `write_image("out/frame.png", rgb, exposure=0.5, tonemap="aces")`; `exposure` and
`tonemap` only change PNG output, the float formats always hold the radiance as rendered.

The EXR codec is written here in NumPy (plus zlib) rather than taken from a dependency: the
layout is small and documented ("OpenEXR File Layout", openexr.com), and a farm worker should not
need a C++ imaging stack to save a frame.
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

# --- OpenEXR constants (OpenEXR File Layout, "Header Attributes" and "Scan Line Blocks") ---------
_EXR_MAGIC = 20000630
_EXR_VERSION = 2
_EXR_FLAG_TILED = 0x200
_EXR_FLAG_NON_IMAGE = 0x800  # deep data
_EXR_FLAG_MULTIPART = 0x1000
_EXR_PIXEL_DTYPES = {0: np.dtype("<u4"), 1: np.dtype("<f2"), 2: np.dtype("<f4")}  # UINT HALF FLOAT
_EXR_COMPRESSIONS = ("NONE", "RLE", "ZIPS", "ZIP", "PIZ", "PXR24", "B44", "B44A", "DWAA", "DWAB")
# Scan lines stored together in one chunk, indexed like _EXR_COMPRESSIONS.
_EXR_LINES_PER_CHUNK = (1, 1, 1, 16, 32, 16, 32, 32, 32, 256)
_EXR_NONE, _EXR_ZIPS, _EXR_ZIP = 0, 2, 3


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
    ext = _extension(path)
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
    """Decode a single-part scanline OpenEXR file to float32 HxWx3.

    Channels R, G, B are used (a luminance-only file's Y is copied to all three); others such as
    A are ignored. Pixel types UINT, HALF and FLOAT; compression NONE, ZIPS and ZIP, plus chunks
    of any other compression that the writer stored raw because compressing did not shrink them.
    """
    if len(data) < 8:
        raise ValueError(f"{name}: not an OpenEXR file (too short)")
    magic, version = struct.unpack_from("<ii", data, 0)
    if magic != _EXR_MAGIC:
        raise ValueError(f"{name}: not an OpenEXR file (bad magic number)")
    if version & 0xFF != _EXR_VERSION:
        raise ValueError(f"{name}: OpenEXR version {version & 0xFF} is not supported")
    if version & (_EXR_FLAG_TILED | _EXR_FLAG_NON_IMAGE | _EXR_FLAG_MULTIPART):
        raise ValueError(f"{name}: tiled, deep and multi-part OpenEXR files are not supported")

    attributes, pos = _exr_read_header(data, name)
    for required in ("channels", "compression", "dataWindow"):
        if required not in attributes:
            raise ValueError(f"{name}: OpenEXR header has no {required!r} attribute")
    channels = _exr_parse_channels(attributes["channels"], name)
    code = attributes["compression"][0]
    if code >= len(_EXR_COMPRESSIONS):
        raise ValueError(f"{name}: unknown OpenEXR compression code {code}")
    x_min, y_min, x_max, y_max = struct.unpack("<iiii", attributes["dataWindow"])
    width, height = x_max - x_min + 1, y_max - y_min + 1
    if width <= 0 or height <= 0:
        raise ValueError(f"{name}: empty OpenEXR data window")

    # One scan line as a structured record: a run of `width` samples for each channel in turn.
    line_dtype = np.dtype([(ch, dtype, (width,)) for ch, dtype in channels])
    lines_per_chunk = _EXR_LINES_PER_CHUNK[code]
    n_chunks = -(-height // lines_per_chunk)
    if pos + 8 * n_chunks > len(data):
        raise ValueError(f"{name}: truncated OpenEXR offset table")
    offsets = np.frombuffer(data, "<u8", n_chunks, pos)

    lines = np.empty(height, line_dtype)
    filled = np.zeros(height, bool)
    for offset in offsets.tolist():
        if offset + 8 > len(data):
            raise ValueError(f"{name}: OpenEXR chunk offset {offset} is past the end of the file")
        y, size = struct.unpack_from("<ii", data, offset)
        row = y - y_min
        if row < 0 or row >= height or row % lines_per_chunk:
            raise ValueError(f"{name}: OpenEXR chunk has scan line {y} outside the data window")
        n_lines = min(lines_per_chunk, height - row)
        expected = n_lines * line_dtype.itemsize
        chunk = data[offset + 8 : offset + 8 + size]
        if len(chunk) != size or size > expected:
            raise ValueError(f"{name}: corrupt OpenEXR chunk at scan line {y}")
        if size < expected:
            # Smaller than raw means compressed; equal means stored raw whatever the method.
            if code not in (_EXR_ZIPS, _EXR_ZIP):
                raise ValueError(
                    f"{name}: OpenEXR compression {_EXR_COMPRESSIONS[code]} is not supported "
                    "(NONE, ZIPS and ZIP are); re-save the file with one of those"
                )
            chunk = _zip_decode(chunk, expected, name)
        lines[row : row + n_lines] = np.frombuffer(chunk, line_dtype, n_lines)
        filled[row : row + n_lines] = True
    if not filled.all():
        missing = int(np.argmin(filled)) + y_min
        raise ValueError(f"{name}: OpenEXR file is incomplete (scan line {missing} is missing)")

    names = [ch for ch, _ in channels]
    if {"R", "G", "B"} <= set(names):
        planes = [lines["R"], lines["G"], lines["B"]]
    elif "Y" in names:
        planes = [lines["Y"]] * 3
    else:
        raise ValueError(f"{name}: OpenEXR file has no R, G, B or Y channels (has {names})")
    return np.stack(planes, axis=-1).astype(np.float32)


def _exr_attribute(name: str, type_name: str, value: bytes) -> bytes:
    size = struct.pack("<i", len(value))
    return name.encode() + b"\0" + type_name.encode() + b"\0" + size + value


def _exr_read_header(data: bytes, name: str) -> tuple[dict[str, bytes], int]:
    """Attributes as raw bytes by name, and the position just past the header."""
    attributes = {}
    pos = 8
    try:
        while data[pos] != 0:
            end = data.index(b"\0", pos)
            attr_name = data[pos:end].decode("latin-1")
            type_end = data.index(b"\0", end + 1)
            (size,) = struct.unpack_from("<i", data, type_end + 1)
            start = type_end + 5
            if size < 0 or start + size > len(data):
                raise ValueError
            attributes[attr_name] = data[start : start + size]
            pos = start + size
    except (IndexError, ValueError, struct.error):
        raise ValueError(f"{name}: truncated or corrupt OpenEXR header") from None
    return attributes, pos + 1


def _exr_parse_channels(chlist: bytes, name: str) -> list[tuple[str, np.dtype]]:
    channels = []
    pos = 0
    while pos < len(chlist) and chlist[pos] != 0:
        end = chlist.index(b"\0", pos)
        channel = chlist[pos:end].decode("latin-1")
        pixel_type, _, x_sampling, y_sampling = struct.unpack_from("<iB3xii", chlist, end + 1)
        if pixel_type not in _EXR_PIXEL_DTYPES:
            raise ValueError(f"{name}: channel {channel!r} has unknown pixel type {pixel_type}")
        if (x_sampling, y_sampling) != (1, 1):
            raise ValueError(f"{name}: subsampled channel {channel!r} is not supported")
        channels.append((channel, _EXR_PIXEL_DTYPES[pixel_type]))
        pos = end + 17
    if not channels:
        raise ValueError(f"{name}: OpenEXR file has no channels")
    return channels


def _zip_encode(raw: bytes) -> bytes:
    """OpenEXR ZIP: split even/odd bytes, delta-code them, deflate (ImfZip.cpp)."""
    t = np.frombuffer(raw, np.uint8)
    # Bytes of the same significance end up next to each other, which deflate rewards.
    t = np.concatenate([t[0::2], t[1::2]])
    d = t.copy()
    d[1:] = t[1:] - t[:-1] + np.uint8(128)  # uint8 arithmetic wraps mod 256, as in the C code
    return zlib.compress(d.tobytes())


def _zip_decode(chunk: bytes, expected: int, name: str) -> bytes:
    try:
        d = np.frombuffer(zlib.decompress(chunk), np.uint8)
    except zlib.error as error:
        raise ValueError(f"{name}: corrupt ZIP-compressed OpenEXR chunk ({error})") from None
    if d.size != expected:
        raise ValueError(f"{name}: ZIP-compressed OpenEXR chunk has the wrong size")
    # Undo the predictor: t[i] = t[i-1] + d[i] - 128, a running sum mod 256.
    d = d.copy()
    d[1:] -= np.uint8(128)
    t = np.cumsum(d, dtype=np.uint8)
    raw = np.empty_like(t)
    half = (t.size + 1) // 2
    raw[0::2] = t[:half]
    raw[1::2] = t[half:]
    return raw.tobytes()


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


# --- helpers --------------------------------------------------------------------------------------


def _extension(path: str | os.PathLike) -> str:
    ext = Path(path).suffix.lower()
    if ext not in SUPPORTED_EXTENSIONS:
        raise ValueError(
            f"{path}: unsupported image extension {ext or '(none)'!r}; "
            f"supported: {', '.join(SUPPORTED_EXTENSIONS)}"
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
