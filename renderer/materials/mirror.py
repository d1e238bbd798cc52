"""Perfect specular reflection with a constant ``reflectance`` (RGB) in ``param[0:3]``."""

from __future__ import annotations

from renderer.jit import kernel
from renderer.materials.fresnel import reflect


@kernel
def mirror_sample(param, wo, n):
    return reflect(wo, n), (param[0], param[1], param[2])
