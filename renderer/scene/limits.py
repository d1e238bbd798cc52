"""Resource limits on a scene: how big a job one scene may ask for.

Every scene that enters Lucent (from the HTTP API, the CLI or a worker) is checked against these
limits before any work is done, so that a typo such as ``"spp": 6400000`` is refused at once instead
of tying up the farm. Each limit can be changed from the environment with the ``LUCENT_`` prefix:

=================  =============  ========================  =================================
Field              Default        Environment variable      What it bounds
=================  =============  ========================  =================================
``max_width``      8192           ``LUCENT_MAX_WIDTH``      ``film.width``
``max_height``     8192           ``LUCENT_MAX_HEIGHT``     ``film.height``
``max_pixels``     16 777 216     ``LUCENT_MAX_PIXELS``     ``film.width * film.height``
``max_spp``        65 536         ``LUCENT_MAX_SPP``        ``render.spp``
``max_depth``      100 000        ``LUCENT_MAX_DEPTH``      a finite ``render.max_depth``
``max_objects``    10 000         ``LUCENT_MAX_OBJECTS``    ``len(objects)``
``max_triangles``  4 000 000      ``LUCENT_MAX_TRIANGLES``  triangles over all meshes
``max_lights``     1 000          ``LUCENT_MAX_LIGHTS``     ``len(lights)``
``max_materials``  1 000          ``LUCENT_MAX_MATERIALS``  ``len(materials)``
``max_environment  8192           ``LUCENT_MAX_ENVIRONMENT  the environment image's width and
_side``                           _SIDE``                   height, each
``max_texture      8192           ``LUCENT_MAX_TEXTURE      a texture image's width and
_side``                           _SIDE``                   height, each
``max_texels``     67 108 864     ``LUCENT_MAX_TEXELS``     texels over all images of a scene
=================  =============  ========================  =================================

``Limits()`` reads the environment each time it is built; ``Limits(max_spp=128)`` overrides one
limit in code (arguments win over the environment).
"""

from __future__ import annotations

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

ENV_PREFIX = "LUCENT_"


class Limits(BaseSettings):
    """Upper bounds that ``load_scene`` enforces on every scene."""

    model_config = SettingsConfigDict(
        env_prefix=ENV_PREFIX,
        # Other services share the LUCENT_ prefix (LUCENT_CACHE_DIR, ...): ignore what is not ours.
        extra="ignore",
        use_attribute_docstrings=True,
        frozen=True,
    )

    max_width: int = Field(default=8192, ge=1)
    """The widest film, in pixels."""

    max_height: int = Field(default=8192, ge=1)
    """The tallest film, in pixels."""

    max_pixels: int = Field(default=16_777_216, ge=1)
    """The most pixels in one image (4096²): bounds the sample buffers a job allocates."""

    max_spp: int = Field(default=65_536, ge=1)
    """The most samples per pixel."""

    max_depth: int = Field(default=100_000, ge=0)
    """The largest finite ``render.max_depth`` (``-1``, unlimited with Russian roulette, is always
    allowed)."""

    max_objects: int = Field(default=10_000, ge=1)
    """The most entries in ``objects`` (a mesh counts as one object)."""

    max_triangles: int = Field(default=4_000_000, ge=1)
    """The most triangles over all meshes of a scene, inline and read from files."""

    max_lights: int = Field(default=1_000, ge=0)
    """The most entries in ``lights`` (emissive objects are not counted here)."""

    max_materials: int = Field(default=1_000, ge=1)
    """The most entries in ``materials``."""

    max_environment_side: int = Field(default=8192, ge=2)
    """The widest and tallest environment image, in texels (an 8192 × 4096 latitude–longitude
    image holds 384 MiB as float32 RGB, and its sampling tables twice that)."""

    max_texture_side: int = Field(default=8192, ge=1)
    """The widest and tallest texture image, in texels."""

    max_texels: int = Field(default=67_108_864, ge=1)
    """The most texels over all the images a scene reads (textures and the environment)."""

    @classmethod
    def env_name(cls, field: str) -> str:
        """The environment variable that sets ``field`` (``max_spp`` -> ``LUCENT_MAX_SPP``)."""
        if field not in cls.model_fields:
            raise KeyError(field)
        return f"{ENV_PREFIX}{field.upper()}"
