"""Write the textures and the mesh of ``examples/textured_floor.json``, all made by formula.

    python examples/make_textured_floor.py

- ``examples/textures/tiles.png``: 2 × 2 terracotta and sandstone floor tiles with grout between
  them, each tile's colour varied a little and speckled (an 8-bit sRGB PNG, 256 × 256); the
  scene repeats it with ``scale``.
- ``examples/textures/bands.png``: latitude bands and one meridian stripe (16-bit sRGB PNG,
  128 × 64), to show a mesh's own texture coordinates.
- ``examples/meshes/uv_sphere.obj``: a sphere of 48 × 32 quads (``meshgen.uv_sphere``) with
  ``vt`` (the sphere's parametrization of the scene format) and ``vn`` (its radial normals:
  smooth shading).
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

from renderer.film.tonemap import linear_to_srgb  # lucent installed (pip install -e .)
from renderer.geometry.meshgen import uv_sphere

TERRACOTTA = np.array([0.50, 0.20, 0.10])
SANDSTONE = np.array([0.62, 0.52, 0.38])
GROUT = np.array([0.30, 0.29, 0.27])


def tiles(size: int = 256, seed: int = 7) -> np.ndarray:
    """Linear albedo (size, size, 3): a 2 × 2 checker of terracotta and sandstone tiles."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size] / size
    tile = (np.floor(2 * x) + np.floor(2 * y)) % 2
    base = np.where(tile[..., None] == 0, TERRACOTTA, SANDSTONE)
    # each tile a little lighter or darker, and speckled
    shade = 1.0 + 0.08 * rng.standard_normal((2, 2))[np.floor(2 * y).astype(int),
                                                      np.floor(2 * x).astype(int)]
    speckle = 1.0 + 0.06 * rng.standard_normal((size, size))
    albedo = base * (shade * speckle)[..., None]
    # grout: a line of 1/40 of a tile at each tile's edge (the image repeats, so one edge each)
    gx = np.minimum(np.mod(2 * x, 1.0), 1.0 - np.mod(2 * x, 1.0))
    gy = np.minimum(np.mod(2 * y, 1.0), 1.0 - np.mod(2 * y, 1.0))
    grout = np.minimum(gx, gy) < 0.0125
    albedo[grout] = GROUT
    return np.clip(albedo, 0.0, 1.0)


def bands(width: int = 128, height: int = 64) -> np.ndarray:
    """Linear albedo (height, width, 3): blue and white latitude bands, a red meridian stripe."""
    y, x = np.mgrid[0:height, 0:width]
    band = (y * 8 // height) % 2
    albedo = np.where(band[..., None] == 0, [0.10, 0.25, 0.60], [0.80, 0.80, 0.75])
    albedo[(x * 16 // width) == 7] = [0.70, 0.08, 0.05]  # u in [7/16, 1/2): facing +z
    return albedo


def write_png(path: Path, albedo: np.ndarray, bits: int = 8) -> None:
    """An RGB PNG of sRGB-encoded ``albedo``, 8 or 16 bits per channel (PNG specification:
    IHDR, one IDAT, IEND; rows unfiltered)."""
    encoded = linear_to_srgb(albedo)
    h, w, _ = albedo.shape
    dtype, top = (">u2", 65535) if bits == 16 else ("u1", 255)
    pixels = np.round(encoded * top).astype(dtype).reshape(h, -1).view(np.uint8)
    raw = np.concatenate([np.zeros((h, 1), np.uint8), pixels], axis=1).tobytes()

    def chunk(kind: bytes, data: bytes) -> bytes:
        crc = struct.pack(">I", zlib.crc32(kind + data))
        return struct.pack(">I", len(data)) + kind + data + crc

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"\x89PNG\r\n\x1a\n"
                     + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, bits, 2, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


def write_obj_with_attributes(path: Path, vertices, triangles, normals, uvs) -> None:
    """``v``, ``vt``, ``vn`` lines and faces ``f i/i/i`` (one index for all three)."""
    lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in vertices]
    lines += [f"vt {u:.9g} {v:.9g}" for u, v in uvs]
    lines += [f"vn {x:.9g} {y:.9g} {z:.9g}" for x, y, z in normals]
    lines += ["f " + " ".join(f"{i + 1}/{i + 1}/{i + 1}" for i in t) for t in triangles]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("# a UV sphere: positions, texture coordinates, normals\n"
                    + "\n".join(lines) + "\n")


def main() -> int:
    examples = Path(__file__).resolve().parent
    write_png(examples / "textures" / "tiles.png", tiles())
    write_png(examples / "textures" / "bands.png", bands(), bits=16)
    vertices, triangles, normals, uvs = uv_sphere(48, 32)
    write_obj_with_attributes(examples / "meshes" / "uv_sphere.obj", vertices, triangles,
                              normals, uvs)
    print("wrote examples/textures/tiles.png, examples/textures/bands.png, "
          f"examples/meshes/uv_sphere.obj ({len(triangles)} triangles)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
