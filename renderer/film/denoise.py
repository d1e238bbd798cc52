"""Denoising with Intel Open Image Denoise (OIDN), through the ``pyoidn`` binding (an optional
extra: ``pip install lucent[denoise]``).

``denoise(beauty, albedo, normal)`` runs OIDN's ``RT`` filter in HDR mode on a frame's mean
radiance, guided by the albedo and normal AOVs of ``renderer.film.aov`` (traced with a few rays
a pixel: nearly noise-free, but OIDN still prefilters them, ``clean_aux=False``, since their
antialiased edges come from random jitter). The result is a biased estimate: OIDN's network
trades the noise for blur, which loses detail finer than the noise (a caustic's edge, a texture
under a few samples) and never converges to the reference however many samples the input has.
"""

from __future__ import annotations

import numpy as np

MISSING = ("denoising (--denoise) needs Intel Open Image Denoise's Python binding: "
           "pip install 'pyoidn>=2.5' (or the package's extra: pip install 'lucent[denoise]')")


def oidn_available() -> bool:
    """Whether ``pyoidn`` can be imported here."""
    try:
        import pyoidn  # noqa: F401
    except ImportError:
        return False
    return True


def denoise(beauty: np.ndarray, albedo: np.ndarray | None = None,
            normal: np.ndarray | None = None, *, quality: str = "high") -> np.ndarray:
    """The denoised (h, w, 3) float32 image of linear HDR ``beauty`` (h, w, 3), with the
    optional albedo and normal AOVs (both or neither). Negative and non-finite radiance (which
    the sample buffers never hold, but a caller may pass) is set to 0 first: OIDN's HDR input is
    non-negative. Raises ``ImportError`` naming ``--denoise`` when ``pyoidn`` is absent."""
    try:
        import pyoidn
    except ImportError as exc:
        raise ImportError(MISSING) from exc
    beauty = np.asarray(beauty)
    if beauty.ndim != 3 or beauty.shape[2] != 3:
        raise ValueError(f"denoise: expected an HxWx3 image, got shape {beauty.shape}")
    if (albedo is None) != (normal is None):
        raise ValueError("denoise: give both the albedo and the normal AOV, or neither")
    color = np.nan_to_num(beauty.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    color = np.ascontiguousarray(np.maximum(color, 0.0))
    aux = {}
    if albedo is not None:
        aux["albedo"] = np.ascontiguousarray(np.clip(albedo, 0.0, 1.0), np.float32)
        aux["normal"] = np.ascontiguousarray(np.clip(normal, -1.0, 1.0), np.float32)
    out = pyoidn.denoise(color, hdr=True, quality=quality, filter_type="RT", **aux)
    return np.asarray(out, np.float32)
