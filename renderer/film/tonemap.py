"""Tone mapping and sRGB encoding: linear radiance to 8-bit display values.

| Parameter  | Default   | Meaning                                                        |
|------------|-----------|----------------------------------------------------------------|
| `exposure` | `0.0`     | stops; the image is multiplied by `2**exposure` first          |
| `tonemap`  | `"clamp"` | `"clamp"`, `"reinhard"` or `"aces"` (see `TONEMAPS`)           |

Example: `to_srgb8(rgb, exposure=1.0, tonemap="aces")` brightens by one stop, then rolls off the
highlights with the ACES fit before the sRGB transfer function and 8-bit quantization.
"""

import numpy as np

TONEMAPS = ("clamp", "reinhard", "aces")

# IEC 61966-2-1 sRGB transfer function constants.
_SRGB_LINEAR_CUTOFF = 0.0031308  # linear value where the OETF switches from the line to the power
_SRGB_ENCODED_CUTOFF = 0.04045  # the same point on the encoded side (12.92 * 0.0031308, rounded)

# Narkowicz 2015, "ACES Filmic Tone Mapping Curve": a rational fit to ODT(RRT(x)). The fit is
# pre-exposed so that 1.0 maps to about 0.8; multiply by 0.6 first for the original ACES curve.
_ACES_A, _ACES_B, _ACES_C, _ACES_D, _ACES_E = 2.51, 0.03, 2.43, 0.59, 0.14


def linear_to_srgb(x: np.ndarray | float) -> np.ndarray:
    """The sRGB OETF: linear [0, 1] to encoded [0, 1], exact piecewise form (IEC 61966-2-1)."""
    x = np.asarray(x)
    if not np.issubdtype(x.dtype, np.floating):
        x = x.astype(np.float64)
    # Clamp the power branch's argument: np.where evaluates both branches, and a negative base
    # would raise a warning and give NaN even where the linear branch is selected.
    power = 1.055 * np.power(np.maximum(x, _SRGB_LINEAR_CUTOFF), 1.0 / 2.4) - 0.055
    return np.where(x <= _SRGB_LINEAR_CUTOFF, 12.92 * x, power).astype(x.dtype, copy=False)


def srgb_to_linear(x: np.ndarray | float) -> np.ndarray:
    """The inverse of `linear_to_srgb`: encoded [0, 1] to linear [0, 1]."""
    x = np.asarray(x)
    if not np.issubdtype(x.dtype, np.floating):
        x = x.astype(np.float64)
    power = np.power((np.maximum(x, _SRGB_ENCODED_CUTOFF) + 0.055) / 1.055, 2.4)
    return np.where(x <= _SRGB_ENCODED_CUTOFF, x / 12.92, power).astype(x.dtype, copy=False)


def apply_tonemap(x: np.ndarray, tonemap: str = "clamp") -> np.ndarray:
    """Map linear values in [0, inf) to [0, 1] with one of `TONEMAPS`."""
    # Both curves have saturated to code 255 long before 1e6, and the cap keeps the squares in the
    # ACES fit (and inf from an overflowed exposure) from turning into inf / inf = NaN.
    if tonemap != "clamp":
        x = np.clip(x, 0.0, 1e6)
    if tonemap == "clamp":
        # Mitsuba's behaviour when it writes an 8-bit image: no curve, just clip.
        return np.clip(x, 0.0, 1.0)
    if tonemap == "reinhard":
        # Reinhard et al. 2002, eq. 3, per channel; negatives were clipped above because
        # x / (1 + x) has a pole at -1.
        return x / (1.0 + x)
    if tonemap == "aces":
        y = (x * (_ACES_A * x + _ACES_B)) / (x * (_ACES_C * x + _ACES_D) + _ACES_E)
        return np.clip(y, 0.0, 1.0)
    raise ValueError(f"unknown tonemap {tonemap!r}; expected one of {', '.join(TONEMAPS)}")


def to_srgb8(rgb: np.ndarray, exposure: float = 0.0, tonemap: str = "clamp") -> np.ndarray:
    """Linear HxWx3 radiance to a displayable uint8 HxWx3 sRGB image.

    Steps: scale by `2**exposure`, tone map to [0, 1], sRGB OETF, round to the nearest code.
    """
    if tonemap not in TONEMAPS:
        raise ValueError(f"unknown tonemap {tonemap!r}; expected one of {', '.join(TONEMAPS)}")
    if not np.isfinite(exposure):
        raise ValueError(f"exposure must be a finite number of stops, got {exposure!r}")
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"expected an HxWx3 image, got shape {rgb.shape}")
    # float32 is plenty for an 8-bit result and halves the memory of a large preview.
    x = rgb.astype(np.float32)
    # A PNG preview must never crash or smear on one bad pixel (NaN would also poison the
    # cast to uint8); the renderer reports dropped samples separately, so black is enough here.
    x[~np.isfinite(x)] = 0.0
    x *= np.float32(2.0**exposure)
    encoded = linear_to_srgb(apply_tonemap(x, tonemap))
    # floor(v + 0.5) rounds halves up, the usual convention for display quantization.
    return np.floor(encoded * 255.0 + 0.5).clip(0, 255).astype(np.uint8)
