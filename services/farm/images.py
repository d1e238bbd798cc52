"""A merged image as the API serves it: EXR (linear float32), NPY (the same array) or PNG (after
exposure and a tone map, 8-bit sRGB). The archive writes a finished job's EXR and default PNG with
these, so a stored image is byte for byte what the live route served."""

from __future__ import annotations

import io

import numpy as np

MEDIA = {"png": "image/png", "exr": "image/x-exr", "npy": "application/octet-stream"}


def encode(image: np.ndarray, fmt: str, exposure: float = 0.0, tonemap: str = "clamp") -> bytes:
    """``image`` (h, w, 3) float32 in ``fmt``; ``exposure`` (stops) and ``tonemap`` for PNG."""
    if fmt == "npy":
        out = io.BytesIO()
        np.save(out, image, allow_pickle=False)
        return out.getvalue()
    if fmt == "exr":
        from renderer.film.image_io import encode_exr

        return encode_exr(image)
    from PIL import Image

    from renderer.film.tonemap import to_srgb8

    out = io.BytesIO()
    Image.fromarray(to_srgb8(image, exposure=exposure, tonemap=tonemap)).save(out, format="PNG")
    return out.getvalue()


def decode_exr(data: bytes) -> np.ndarray:
    from renderer.film.image_io import decode_exr as decode

    return decode(data, name="stored image").astype(np.float32)
