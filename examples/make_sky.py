"""Write a procedural sky as a latitude–longitude EXR: an environment image for ``environment``.

    python examples/make_sky.py examples/sky.exr --width 1024 --height 512

The image follows the scene format's mapping (u = atan2(x, −z)/2π to the right, +Y the top row):

- sky: a gradient from a deep blue zenith to a pale horizon (more blue scattered near the
  zenith, the horizon whitened by the longer path through the air), brightened towards the sun
  (a forward-scattering glow, Henyey–Greenstein g = 0.75);
- sun: a disc of angular radius ``--sun-radius`` (degrees, larger than the real 0.27° so that a
  small image resolves it) whose radiance gives ``--sun-irradiance`` (W/m², per channel times a
  warm white) on a surface facing it, at ``--sun-elevation`` above the horizon and
  ``--sun-azimuth`` degrees from −Z towards +X (u = azimuth/360);
- ground: below the horizon, a diffuse ground of albedo ``--ground`` lit by the sun and the sky
  (its radiance ρ/π times the irradiance on a horizontal surface), fading into a soft horizon.

Linear radiance, RGB, ZIP-compressed, HALF (16-bit float: 3 significant digits, up to 65504, as
HDRI sites ship them; ``--pixel-type FLOAT`` for 32-bit). Each texel holds the radiance at its
direction (the environment looks up texels at column centres (i + ½)/W and rows j/(H − 1) from
pole to pole).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # runnable as a plain script from anywhere
    sys.path.insert(0, str(ROOT))

from renderer.film.image_io import encode_exr  # noqa: E402

ZENITH = np.array([0.10, 0.22, 0.60])
HORIZON = np.array([0.70, 0.80, 0.95])
SUN_COLOUR = np.array([1.0, 0.93, 0.82])


def texel_directions(width: int, height: int) -> np.ndarray:
    """(H, W, 3) unit directions of the texels, by the environment's mapping."""
    u = (np.arange(width) + 0.5) / width
    v = np.arange(height) / (height - 1)
    phi, theta = 2 * np.pi * u[None, :], np.pi * v[:, None]
    return np.stack(np.broadcast_arrays(np.sin(phi) * np.sin(theta), np.cos(theta),
                                        -np.cos(phi) * np.sin(theta)), axis=-1)


def sun_direction(elevation: float, azimuth: float) -> np.ndarray:
    e, a = math.radians(elevation), math.radians(azimuth)
    return np.array([math.sin(a) * math.cos(e), math.sin(e), -math.cos(a) * math.cos(e)])


def make_sky(width: int = 1024, height: int = 512, *, sun_elevation: float = 35.0,
             sun_azimuth: float = 60.0, sun_radius: float = 1.5, sun_irradiance: float = 6.0,
             sky_brightness: float = 1.0, ground=(0.35, 0.3, 0.25)) -> np.ndarray:
    """The sky as float32 (height, width, 3) linear radiance."""
    d = texel_directions(width, height)
    s = sun_direction(sun_elevation, sun_azimuth)
    cos_sun = d @ s
    up = np.clip(d[..., 1], 0.0, 1.0)

    # Sky: zenith to horizon, with a glow about the sun (Henyey–Greenstein, g = 0.75)
    t = up[..., None] ** 0.45
    sky = (1 - t) * HORIZON + t * ZENITH
    g = 0.75
    glow = (1 - g * g) / (1 + g * g - 2 * g * cos_sun) ** 1.5 / (4 * np.pi)
    sky = sky_brightness * (sky + 0.35 * glow[..., None] * SUN_COLOUR)

    # Sun: a disc of solid angle Ω = 2π(1 − cos r) with radiance E/Ω
    omc = 1.0 - math.cos(math.radians(sun_radius))
    in_disc = cos_sun >= 1.0 - omc
    sun_radiance = sun_irradiance / (2 * np.pi * omc) * SUN_COLOUR

    # Ground: ρ/π times the horizontal irradiance of the sun and the sky above (π·mean sky
    # radiance, as from a uniform sky), fading over a few degrees below the horizon
    e_sun = sun_irradiance * max(0.0, math.sin(math.radians(sun_elevation))) * SUN_COLOUR
    mean_sky = sky[d[..., 1] > 0].mean(axis=0)
    ground_radiance = np.asarray(ground) / np.pi * (e_sun + np.pi * mean_sky)
    below = np.clip(-d[..., 1] / math.sin(math.radians(4.0)), 0.0, 1.0)[..., None]
    horizon_haze = sky * (1 - below) + ground_radiance * below

    image = np.where((d[..., 1] >= 0)[..., None], sky, horizon_haze)
    image[in_disc & (d[..., 1] > 0)] = sun_radiance
    return image.astype(np.float32)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="the EXR file to write")
    parser.add_argument("--width", type=int, default=1024)
    parser.add_argument("--height", type=int, default=512)
    parser.add_argument("--sun-elevation", type=float, default=35.0, help="degrees")
    parser.add_argument("--sun-azimuth", type=float, default=60.0,
                        help="degrees from -Z towards +X")
    parser.add_argument("--sun-radius", type=float, default=1.5, help="degrees")
    parser.add_argument("--sun-irradiance", type=float, default=6.0, help="W/m² facing the sun")
    parser.add_argument("--sky-brightness", type=float, default=1.0)
    parser.add_argument("--ground", type=float, nargs=3, default=(0.35, 0.3, 0.25),
                        help="the ground's albedo (RGB)")
    parser.add_argument("--pixel-type", choices=("HALF", "FLOAT"), default="HALF")
    args = parser.parse_args(argv)
    if args.width < 2 or args.height < 2:
        parser.error("--width and --height must be at least 2")
    image = make_sky(args.width, args.height, sun_elevation=args.sun_elevation,
                     sun_azimuth=args.sun_azimuth, sun_radius=args.sun_radius,
                     sun_irradiance=args.sun_irradiance, sky_brightness=args.sky_brightness,
                     ground=args.ground)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if args.pixel_type == "HALF" and image.max() > 65504.0:
        parser.error(f"the sun's radiance {image.max():.4g} exceeds HALF's range: --pixel-type "
                     "FLOAT, or a larger --sun-radius")
    args.out.write_bytes(encode_exr(image, compression="ZIP", pixel_type=args.pixel_type))
    print(f"{args.out}: {args.width}x{args.height}, radiance {image.min():.3g}..{image.max():.3g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
