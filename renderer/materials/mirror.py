"""Perfect specular reflection with a constant ``reflectance`` (RGB) in
``param[REFLECTANCE:REFLECTANCE + 3]`` (``pack_mirror``)."""

from __future__ import annotations

from renderer.jit import kernel
from renderer.materials.fresnel import reflect

REFLECTANCE = 0


def pack_mirror(p, m) -> None:
    """Write a ``mirror`` material's row into ``p``."""
    p[REFLECTANCE:REFLECTANCE + 3] = m.reflectance


@kernel
def mirror_sample(param, wo, n):
    return reflect(wo, n), (param[REFLECTANCE], param[REFLECTANCE + 1], param[REFLECTANCE + 2])
