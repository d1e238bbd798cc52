"""Scene format v1: the pydantic models of a scene document.

The names and meanings follow the public contract (``SCENE_FORMAT.md``); ``docs/scene-format.md``
is the user's reference to every field, default and range. These models check what each part of a
scene can check about itself (types, ranges, a camera whose ``up`` is not the viewing direction, a
quad that is not degenerate, ...). What needs the whole scene or bulk arrays (material
references, mesh indices and closedness, resource limits, reading mesh files) is checked by
``renderer.scene.load.load_scene``: always load scenes through it, never with
``Scene.model_validate`` alone.

==================  ===========================================================================
Model               JSON
==================  ===========================================================================
``Camera``          ``camera``: ``position``, ``look_at``, ``up`` = [0, 1, 0], ``fov`` = 39
``Film``            ``film``: ``width``, ``height``
``RenderSettings``  ``render``: ``spp`` = 64, ``max_depth`` = -1, ``seed`` = 0
``Material``        ``materials.NAME``: diffuse | phong | mirror | dielectric | translucent
``Object``          ``objects[i]``: sphere | quad | box | mesh
``Light``           ``lights[i]``: point | directional
``Scene``           the document
==================  ===========================================================================
"""

from __future__ import annotations

import math
import re
from itertools import chain
from pathlib import Path
from typing import Annotated, ClassVar, Literal

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    PrivateAttr,
    SerializerFunctionWrapHandler,
    Strict,
    Tag,
    ValidationInfo,
    WithJsonSchema,
    field_validator,
    model_serializer,
    model_validator,
)
from pydantic_core import PydanticCustomError, ValidationError

from renderer.materials.presets import PRESETS

# Numbers are strict: a JSON string ("1.5") or a boolean is not a number, and an integer field
# refuses 2.5 and 2.0 alike. Integers are accepted where a float is expected.
Float = Annotated[float, Strict()]
Int = Annotated[int, Strict()]

Vec3 = tuple[Float, Float, Float]
"""A point or a direction, in scene units."""

NonNegative = Annotated[float, Strict(), Field(ge=0)]
PositiveFloat = Annotated[float, Strict(), Field(gt=0)]
UnitInterval = Annotated[float, Strict(), Field(ge=0, le=1)]

Colour = tuple[NonNegative, NonNegative, NonNegative]
"""Linear RGB, each channel >= 0 (radiance, intensity, absorption, ...)."""

Albedo = tuple[UnitInterval, UnitInterval, UnitInterval]
"""Linear RGB reflectance-like colour, each channel in [0, 1]."""

INT64_MAX = 2**63 - 1

VertexIndex = Annotated[int, Strict(), Field(ge=0, le=INT64_MAX)]
"""An index into the mesh's vertices; the kernels hold indices as int64 (``Mesh.arrays``)."""

CHANNELS = ("red", "green", "blue")
AXES = ("x", "y", "z")

# Relative tolerance under which two directions count as parallel: |a x b| <= EPS_PARALLEL |a||b|,
# i.e. the sine of the angle between them is below 1e-10. Far below any intended geometry, far
# above float64 rounding (about 1e-16), so that exactly collinear input computed with rounding
# errors is still caught.
EPS_PARALLEL = 1e-10


def scene_error(message: str) -> PydanticCustomError:
    """A validation error whose message reaches the user unchanged (no "Value error, " prefix)."""
    return PydanticCustomError("scene", "{message}", {"message": message})


def union_error(message: str):
    """A wrap validator that gives a union field (a number or a triple) one error, ``message``,
    where pydantic would report each branch's under its own tag."""

    def check(value, handler):
        try:
            return handler(value)
        except ValidationError:
            raise scene_error(message) from None

    return check


def format_vec(v: tuple[float, ...] | list[float]) -> str:
    """``[0, 1, 0.5]``: compact, for error messages."""
    return "[" + ", ".join(f"{x:g}" for x in v) + "]"


def _cross(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, float, float]:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _norm(a: tuple[float, ...]) -> float:
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


def nearly_parallel(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    """True if a and b are parallel (or either is zero) to within ``EPS_PARALLEL``."""
    return _norm(_cross(a, b)) <= EPS_PARALLEL * _norm(a) * _norm(b)


def overflows(*vectors: tuple[float, ...]) -> bool:
    """True if a vector's squared length is not a finite float: normalizing it (and the tests
    below) overflow, though each component is finite (1e200: its square is 1e400)."""
    return not all(math.isfinite(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) for v in vectors)


def overflow_message(what: str) -> str:
    """What ``overflows`` found, said as it is rather than as the geometric fault that the
    overflowed numbers would look like (an infinite cross product reads as "parallel")."""
    return (
        f"{what} overflows: its squared length exceeds the largest float (about 1.8e308), "
        "which the renderer cannot compute with; scale the scene down"
    )


def overflow_error(what: str) -> PydanticCustomError:
    return scene_error(overflow_message(what))


def _require_nonzero(v: Vec3) -> Vec3:
    if not any(v):
        raise scene_error("must be a non-zero vector")
    if overflows(v):
        raise overflow_error(f"the vector {format_vec(v)}")
    return v


class SceneModel(BaseModel):
    """Base of every scene model: unknown fields and non-finite numbers are errors."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=False)


# --- File references (v1.1, "Files: paths and assets"; read by renderer.scene.files) --------------

ASSET_PATTERN = r"^sha256:[0-9a-f]{64}$"
"""An asset's name: ``sha256:`` and the lowercase hex SHA-256 of its bytes."""



def _check_asset_name(name: str) -> str:
    if not re.fullmatch(ASSET_PATTERN, name):
        raise scene_error('must be "sha256:" and 64 lowercase hex digits (the SHA-256 of the file)')
    return name


AssetName = Annotated[
    str,
    Strict(),
    AfterValidator(_check_asset_name),
    WithJsonSchema({"type": "string", "pattern": ASSET_PATTERN}),
]


class AssetRef(SceneModel):
    """``{"asset": "sha256:<hex>"}``: a file uploaded to the farm (``POST /api/assets``)."""

    asset: AssetName


def _path_allowed(path: str, info: ValidationInfo) -> str:
    # Only the CLI reads files; a server must never open a path that a request names.
    if not (info.context and info.context.get("allow_paths", False)):
        raise scene_error(
            "file paths are accepted only by the command line; upload the file "
            '(POST /api/assets) and give {"asset": "sha256:..."}'
        )
    return path


FilePath = Annotated[str, Strict(), Field(min_length=1)]

FileRef = Annotated[AssetRef | FilePath, Field(union_mode="left_to_right")]
"""A file: a path (the command line only; relative to the scene file) or an uploaded asset.
Fields of this type add ``field_validator(NAME)(check_file_ref)``, which refuses paths unless
``load_scene`` was called with ``allow_paths=True``."""


def check_file_ref(ref: AssetRef | str, info: ValidationInfo) -> AssetRef | str:
    """Field validator of a ``FileRef``: a path only where paths are allowed."""
    return ref if isinstance(ref, AssetRef) else _path_allowed(ref, info)


# --- Textures (v1.1, "Textures, UVs and shading normals"; renderer.textures) ---------------------


class ImageModel(SceneModel):
    """A part of a scene that names an image file (``image``), which ``load_scene`` reads."""

    _pixels: np.ndarray | None = PrivateAttr(default=None)
    _what: ClassVar[str] = "image"

    def pixels(self) -> np.ndarray:
        """The image, linear float32 (H, W, 3), row 0 at the top, as ``load_scene`` read it."""
        if self._pixels is None:
            raise ValueError(f"the {self._what} image has not been read: load the scene with "
                             "load_scene")
        return self._pixels

    def _attach_pixels(self, pixels: np.ndarray) -> None:
        self._pixels = pixels


class BitmapTexture(ImageModel):
    """An image looked up at (u·su + ou, v·sv + ov), bilinear between texel centres, repeating;
    u grows to the right of the image and v upwards ((0, 0) is the bottom-left corner as
    displayed). ``load_scene`` reads the image."""

    type: Literal["bitmap"] = "bitmap"
    image: FileRef
    """PNG (8 or 16 bits per channel), EXR or PFM: a path (the command line) or an asset."""
    srgb: bool | None = None
    """Whether the texels are sRGB-encoded (decoded to linear); default true for PNG, false for
    EXR and PFM."""
    scale: tuple[Float, Float] = (1.0, 1.0)
    offset: tuple[Float, Float] = (0.0, 0.0)

    _check_image = field_validator("image")(check_file_ref)
    _what: ClassVar[str] = "texture"

    @field_validator("scale")
    @classmethod
    def _check_scale(cls, scale: tuple[float, float]) -> tuple[float, float]:
        if scale[0] == 0.0 or scale[1] == 0.0:
            raise scene_error("must be non-zero in u and v")
        return scale


class CheckerboardTexture(SceneModel):
    """``color0`` where floor(u·su) + floor(v·sv) is even, ``color1`` elsewhere."""

    type: Literal["checkerboard"] = "checkerboard"
    color0: Colour = (0.4, 0.4, 0.4)
    color1: Colour = (0.2, 0.2, 0.2)
    scale: tuple[Float, Float] = (2.0, 2.0)
    """Squares per unit of u and of v (2: Mitsuba 3's default checkerboard)."""


Texture = BitmapTexture | CheckerboardTexture

TEXTURE_TYPES = ("bitmap", "checkerboard")


def _colour_kind(value) -> str | None:
    """The branch of a colour parameter: ``rgb`` for a triple, else the texture's type."""
    if value is None:
        return "none"
    if isinstance(value, dict):
        return value.get("type") if value.get("type") in TEXTURE_TYPES else "texture"
    if isinstance(value, (BitmapTexture, CheckerboardTexture)):
        return value.type
    return "rgb"


def _colour_param(rgb, optional: bool = False):
    branches = (Annotated[rgb, Tag("rgb")] | Annotated[BitmapTexture, Tag("bitmap")]
                | Annotated[CheckerboardTexture, Tag("checkerboard")])
    if optional:  # (``X | None`` outside would hash the discriminator's dict)
        branches = branches | Annotated[None, Tag("none")]
    return Annotated[
        branches,
        Discriminator(_colour_kind, custom_error_type="scene", custom_error_message="{message}",
                      custom_error_context={"message": (
                          'must be [r, g, b] or a texture {"type": "bitmap" | "checkerboard", '
                          '...}')}),
    ]


AlbedoParam = _colour_param(Albedo)
OptionalAlbedoParam = _colour_param(Albedo, optional=True)
"""A colour parameter in [0, 1] per channel, or a texture (whose texels must be in [0, 1])."""

ColourParam = _colour_param(Colour)
"""A colour parameter >= 0 per channel, or a texture."""

COLOUR_PARAMS = {"diffuse": ("albedo",), "phong": ("diffuse", "specular"),
                 "mirror": ("reflectance",), "conductor": ("specular",),
                 "translucent": ("albedo",)}
"""The fields of each material type that may be textures (scene format v1.1)."""


def is_texture(value) -> bool:
    return isinstance(value, (BitmapTexture, CheckerboardTexture))


# --- Camera, film and render settings -------------------------------------------------------------


class Camera(SceneModel):
    """A pinhole camera. ``fov`` is the vertical field of view in degrees."""

    position: Vec3
    look_at: Vec3
    up: Vec3 = (0.0, 1.0, 0.0)
    fov: Float = Field(default=39.0, gt=0, lt=180)

    _check_up = field_validator("up")(_require_nonzero)

    @model_validator(mode="after")
    def _check_frame(self) -> Camera:
        forward = tuple(t - p for t, p in zip(self.look_at, self.position, strict=True))
        if not any(forward):
            raise scene_error("look_at must differ from position")
        # The renderer normalizes forward (and up was checked alike): past that, the cross
        # product below may be infinite, but then the two are not parallel.
        if overflows(forward):
            raise overflow_error(
                f"the viewing direction {format_vec(forward)} (look_at - position)"
            )
        # right = normalize(cross(forward, up)) would be NaN: no image orientation.
        if nearly_parallel(forward, self.up):
            raise scene_error(
                f"up {format_vec(self.up)} is parallel to the viewing direction "
                f"{format_vec(forward)} (look_at - position)"
            )
        return self


class Film(SceneModel):
    """The image size in pixels (upper bounds: ``Limits``)."""

    width: Int = Field(ge=1)
    height: Int = Field(ge=1)
    aovs: list[Literal["albedo", "normal", "depth", "variance", "spp"]] = Field(
        default_factory=list, max_length=5)
    """Extra layers written beside the image in a multi-layer EXR (``renderer.film.aov``):
    ``albedo``, ``normal`` and ``depth`` of the first surface that is not a perfect mirror or
    smooth glass, ``variance`` of each pixel's mean and ``spp`` (its sample count)."""


class RenderSettings(SceneModel):
    """Sampling settings: JSON key ``render``."""

    spp: Int = Field(default=64, ge=1)
    """Samples per pixel."""
    max_depth: Int = Field(default=-1, ge=-1)
    """Largest number of scattering events on a path; -1: unlimited (Russian roulette only)."""
    seed: Int = Field(default=0, ge=0, le=INT64_MAX)
    """Same scene, same seed: same image, however it is split into tiles and passes."""
    target_error: Float | None = Field(default=None, gt=0)
    """Adaptive sampling: a pixel stops receiving samples once its estimated relative MSE is
    below this (``spp`` stays the most it gets); unset: every pixel gets ``spp``."""
    sampler: Literal["independent", "sobol"] = "independent"
    """Random numbers of a sample: ``independent`` (every dimension a hash of seed, pixel, sample
    and dimension) or ``sobol`` (the camera jitter and the first vertex's light and BSDF samples
    from shuffled, Owen-scrambled Sobol' (0,2)-sequences per pixel, the rest independent; Burley
    2020): unbiased either way, less noise per sample with ``sobol``."""


# --- Materials ------------------------------------------------------------------------------------


class DiffuseMaterial(SceneModel):
    """Lambertian reflection."""

    type: Literal["diffuse"] = "diffuse"
    albedo: AlbedoParam = (0.5, 0.5, 0.5)


class PhongMaterial(SceneModel):
    """Energy-conserving (normalized) Phong: a Lambertian lobe plus a glossy lobe."""

    type: Literal["phong"] = "phong"
    diffuse: AlbedoParam = (0.5, 0.5, 0.5)
    specular: AlbedoParam = (0.2, 0.2, 0.2)
    exponent: Float = Field(default=30.0, gt=0)

    @model_validator(mode="after")
    def _check_energy(self) -> PhongMaterial:
        # Each lobe is normalized, so the two weights must not sum above 1: the material would
        # reflect more than it receives (a small slack absorbs rounding, e.g. 0.7 + 0.3).
        if is_texture(self.diffuse) or is_texture(self.specular):
            return self  # load_scene checks textured lobes texel by texel
        for c, (kd, ks) in enumerate(zip(self.diffuse, self.specular, strict=True)):
            if kd + ks > 1.0 + 1e-9:
                raise scene_error(
                    f"diffuse + specular must be <= 1 in every channel (energy conservation): "
                    f"{CHANNELS[c]} is {kd:g} + {ks:g} = {kd + ks:g}"
                )
        return self


class MirrorMaterial(SceneModel):
    """Perfect specular reflection."""

    type: Literal["mirror"] = "mirror"
    reflectance: AlbedoParam = (1.0, 1.0, 1.0)


class ConductorMaterial(SceneModel):
    """A smooth metal: mirror reflection weighted by the conductor Fresnel term of its complex
    index of refraction η + ik per channel (``eta`` and ``k``, or a measured ``preset``)."""

    type: Literal["conductor"] = "conductor"
    eta: tuple[PositiveFloat, PositiveFloat, PositiveFloat] | None = None
    """Real part of the complex index of refraction, per channel (with ``k``)."""
    k: Colour | None = None
    """Imaginary part (extinction coefficient), per channel (with ``eta``)."""
    preset: Literal["Au", "Ag", "Cu", "Al"] | None = None
    """A measured metal instead of eta and k (renderer/materials/conductor.py)."""
    specular: ColourParam = (1.0, 1.0, 1.0)
    """A scale on the reflectance, per channel (1: the physical metal)."""
    roughness: Float = Field(default=0.0, ge=0, le=1)
    """GGX α of the surface, as Mitsuba writes it (not a perceptual roughness); 0 is the smooth
    metal."""

    @model_validator(mode="after")
    def _one_form(self) -> ConductorMaterial:
        given = [f for f in ("eta", "k") if getattr(self, f) is not None]
        if self.preset is not None and given:
            raise scene_error(f"preset replaces eta and k; give one form (also given: "
                              f"{', '.join(given)})")
        if self.preset is None and len(given) != 2:
            raise scene_error("a conductor needs eta and k, or a preset (Au, Ag, Cu, Al)")
        return self


class DielectricMaterial(SceneModel):
    """Glass: Fresnel reflection and Snell refraction (smooth, or through GGX microfacets),
    Beer-Lambert absorption inside."""

    type: Literal["dielectric"] = "dielectric"
    ior: Float = Field(default=1.5, gt=0)
    absorption: Colour = (0.0, 0.0, 0.0)
    """Absorption coefficient per unit length: transmittance exp(-absorption * distance)."""
    roughness: Float = Field(default=0.0, ge=0, le=1)
    """GGX α of the surface, as Mitsuba writes it; 0 is smooth glass."""


TranslucentMethod = Literal[
    "volumetric", "single_scatter", "diffuse_entry", "backlight", "diffusion", "auto"
]


# A preset's name: checked against the table (the error lists the known ones); in the JSON
# schema an enum, a name never a path
PresetName = Annotated[str, WithJsonSchema({"type": "string", "enum": sorted(PRESETS)})]


class TranslucentMaterial(SceneModel):
    """Subsurface scattering in a homogeneous medium behind a dielectric boundary."""

    type: Literal["translucent"] = "translucent"
    method: TranslucentMethod = "volumetric"
    ior: Float = Field(default=1.3, ge=1.0)
    albedo: OptionalAlbedoParam = None
    """Single-scattering albedo per channel (default [0.8, 0.8, 0.8]); for the methods
    single_scatter, diffuse_entry and backlight a texture may colour the surface (the medium
    then has the texture's mean albedo)."""
    density: PositiveFloat | tuple[PositiveFloat, PositiveFloat, PositiveFloat] | None = None
    """Extinction coefficient sigma_t per unit length (mean free path 1 / density), one number or
    one per channel (default 1)."""
    sigma_s: Colour | None = None
    """Scattering coefficient per channel, per unit length: with sigma_a, instead of albedo and
    density (albedo = sigma_s / (sigma_s + sigma_a), density = sigma_s + sigma_a)."""
    sigma_a: Colour | None = None
    """Absorption coefficient per channel, per unit length (with sigma_s)."""
    preset: PresetName | None = None
    """A measured medium by name (Jensen et al. 2001, renderer/materials/presets.py) instead of
    the coefficients."""
    preset_scale: Float | None = Field(default=None, gt=0)
    """preset: millimetres per scene unit (10 when a unit is a centimetre; default 1)."""
    g: Float = Field(default=0.0, gt=-1, lt=1)
    """Henyey-Greenstein anisotropy: > 0 forward, < 0 backward."""
    roughness: Float = Field(default=0.0, ge=0, le=1)
    """GGX α of the boundary, as Mitsuba writes it; 0 is the smooth boundary. Rendered by the
    methods in ROUGH_METHODS (single_scatter and backlight have no dielectric boundary); no
    effect at ior 1 (an index-matched boundary neither reflects nor refracts)."""

    # Method-specific knobs (docs/methods/*.md); each is an error with any other method.
    surface_fraction: Float | None = Field(default=None, ge=0, le=1)
    """single_scatter: fraction of hits that scatter as Lambertian at the surface (default 0.8)."""
    direct_light: bool | None = None
    """diffuse_entry: light the surface by a separate direct-light estimate (default false)."""
    specular_exponent: Float | None = Field(default=None, gt=0)
    """diffuse_entry: Phong exponent of the surface coat; unset = a smooth (mirror) coat."""
    distortion: Float | None = Field(default=None, ge=0)
    """backlight: how far the surface normal bends the light vector (default 0.2)."""
    power: Float | None = Field(default=None, gt=0)
    """backlight: exponent of the view-dependent transmission lobe (default 4)."""
    scale: Float | None = Field(default=None, ge=0)
    """backlight: share of light transmitted instead of reflected, clamped to 1 (default 0.5)."""

    _medium: tuple[tuple[float, float, float], tuple[float, float, float]] = PrivateAttr(
        default=((0.8, 0.8, 0.8), (1.0, 1.0, 1.0)))

    _density = field_validator("density", mode="wrap")(union_error(
        "must be a number > 0, or a list of 3 numbers > 0 (σt of each channel)"))

    @field_validator("preset")
    @classmethod
    def _known_preset(cls, name: str | None) -> str | None:
        if name is not None and name not in PRESETS:
            raise scene_error(f"unknown preset {name!r}; known: {', '.join(sorted(PRESETS))}")
        return name

    @model_validator(mode="after")
    def _coefficients(self) -> TranslucentMaterial:
        """One form of the medium's coefficients: albedo and density, sigma_s and sigma_a, or a
        preset; kept as (albedo, sigma_t) per channel (``albedo_rgb``, ``sigma_t``)."""
        given = [f for f in ("albedo", "density", "sigma_s", "sigma_a", "preset")
                 if getattr(self, f) is not None]
        if self.preset is not None and len(given) > 1:
            raise scene_error(f"preset replaces albedo, density, sigma_s and sigma_a; give one "
                              f"form (also given: {', '.join(f for f in given if f != 'preset')})")
        if self.preset_scale is not None and self.preset is None:
            raise scene_error("preset_scale applies to a preset only")
        sigma = [f for f in ("sigma_s", "sigma_a") if getattr(self, f) is not None]
        if sigma and ({"albedo", "density"} & set(given)):
            raise scene_error(f"sigma_s and sigma_a replace albedo and density; give one form "
                              f"(given: {', '.join(given)})")
        if len(sigma) == 1:
            missing = "sigma_a" if sigma == ["sigma_s"] else "sigma_s"
            raise scene_error(f"{sigma[0]} needs {missing} too (or give albedo and density)")
        if self.preset is not None:
            from renderer.materials.presets import preset_coefficients

            s, a = preset_coefficients(self.preset, self.g, self.preset_scale or 1.0)
        elif sigma:
            s, a = self.sigma_s, self.sigma_a  # type: ignore[assignment]
        else:
            albedo = self.albedo if self.albedo is not None else (0.8, 0.8, 0.8)
            if is_texture(albedo):  # the medium's: the texture's mean (set again once read)
                albedo = _texture_mean_or(albedo, (0.8, 0.8, 0.8))
            density = 1.0 if self.density is None else self.density
            sigma_t = (density,) * 3 if isinstance(density, (int, float)) else density
            self._medium = (tuple(float(x) for x in albedo),  # type: ignore[assignment]
                            tuple(float(x) for x in sigma_t))
            return self
        for c in range(3):
            if not s[c] + a[c] > 0.0:
                raise scene_error(f"sigma_s + sigma_a must be > 0 in every channel ({CHANNELS[c]}: "
                                  f"{s[c]:g} + {a[c]:g})")
        self._medium = (tuple(float(s[c] / (s[c] + a[c])) for c in range(3)),  # type: ignore
                        tuple(float(s[c] + a[c]) for c in range(3)))
        return self

    @property
    def albedo_rgb(self) -> tuple[float, float, float]:
        """Single-scattering albedo σs/σt per channel, whichever form the material gives."""
        return self._medium[0]

    @property
    def sigma_t(self) -> tuple[float, float, float]:
        """Extinction σt per channel, per unit length, whichever form the material gives."""
        return self._medium[1]

    @property
    def chromatic(self) -> bool:
        """Whether the channels travel different mean free paths."""
        return len(set(self.sigma_t)) > 1

    @model_validator(mode="after")
    def _check_texture(self) -> TranslucentMaterial:
        if is_texture(self.albedo) and self.method not in TEXTURE_METHODS:
            raise scene_error(
                f"a texture on albedo is rendered by methods {', '.join(TEXTURE_METHODS)} (the "
                f"surface's colour); method {self.method!r} takes an RGB albedo (the albedo "
                "belongs to the medium)")
        return self

    def _read_texture(self) -> None:
        """The medium's albedo from a bitmap texture's mean, once ``load_scene`` has read it."""
        if is_texture(self.albedo) and self.sigma_s is None and self.preset is None:
            self._medium = (_texture_mean_or(self.albedo, self._medium[0]), self._medium[1])

    @model_validator(mode="after")
    def _check_roughness(self) -> TranslucentMaterial:
        if self.roughness > 0.0 and self.method in NO_BOUNDARY_METHODS:
            raise scene_error(
                f"roughness (a rough boundary) is rendered by methods {', '.join(ROUGH_METHODS)}; "
                f"method {self.method!r} has no dielectric boundary to roughen "
                f"({NO_BOUNDARY_METHODS[self.method]})"
            )
        if self.roughness > 0.0 and self.method == "diffuse_entry":
            for knob, why in (("specular_exponent", "a Phong coat, which roughness replaces"),
                              ("direct_light", "its entry weight 1 − F is the smooth coat's")):
                if knob in self.model_fields_set and getattr(self, knob):
                    raise scene_error(
                        f"{knob} and roughness cannot be combined on method 'diffuse_entry' "
                        f"({knob}: {why})")
        return self

    @model_validator(mode="after")
    def _check_knobs(self) -> TranslucentMaterial:
        for knob in sorted(self.model_fields_set):
            owner = METHOD_KNOBS.get(knob)
            if owner is not None and owner != self.method and getattr(self, knob) is not None:
                raise scene_error(
                    f"{knob} applies to method {owner!r} only (this material's method is "
                    f"{self.method!r})"
                )
        return self


# The methods whose albedo may be a texture: it colours their surface (auto: it chooses one of
# them, ``renderer.materials.auto.for_a_texture``).
TEXTURE_METHODS = ("single_scatter", "diffuse_entry", "backlight", "diffusion", "auto")


def _texture_mean_or(texture, default) -> tuple[float, float, float]:
    """A texture's mean colour (a bitmap's once read), else ``default``."""
    if isinstance(texture, BitmapTexture) and texture._pixels is None:
        return tuple(float(x) for x in default)  # type: ignore[return-value]
    from renderer.textures import texture_mean

    return texture_mean(texture)


# The methods that render a rough boundary (``roughness`` > 0): docs/methods/, "Rough coat".
ROUGH_METHODS = ("volumetric", "diffuse_entry", "diffusion", "auto")
# The methods whose surface is no dielectric boundary, with the reason roughness has no meaning
NO_BOUNDARY_METHODS = {
    "single_scatter": "its surface is a Lambertian share and light enters straight, unrefracted",
    "backlight": "its surface is Lambertian and its transmitted light an empirical lobe",
}

# Which method each knob belongs to.
METHOD_KNOBS = {
    "surface_fraction": "single_scatter",
    "direct_light": "diffuse_entry",
    "specular_exponent": "diffuse_entry",
    "distortion": "backlight",
    "power": "backlight",
    "scale": "backlight",
}


Material = Annotated[
    DiffuseMaterial | PhongMaterial | MirrorMaterial | ConductorMaterial | DielectricMaterial
    | TranslucentMaterial,
    Field(discriminator="type"),
]

MATERIAL_TYPES = ("diffuse", "phong", "mirror", "conductor", "dielectric", "translucent")

# Materials with an inside: the objects that carry them must enclose a volume.
VOLUME_MATERIAL_TYPES = ("dielectric", "translucent")


# --- Objects --------------------------------------------------------------------------------------


class ObjectBase(SceneModel):
    """What every object has: a material by name and an optional emitted radiance."""

    material: str
    emission: Colour | None = None


class Sphere(ObjectBase):
    type: Literal["sphere"] = "sphere"
    center: Vec3
    radius: Float = Field(gt=0)


class Quad(ObjectBase):
    """The parallelogram origin + s edge1 + t edge2, s, t in [0, 1]; normal along edge1 x edge2."""

    type: Literal["quad"] = "quad"
    origin: Vec3
    edge1: Vec3
    edge2: Vec3

    @model_validator(mode="after")
    def _check_area(self) -> Quad:
        if overflows(self.edge1, self.edge2, _cross(self.edge1, self.edge2)):
            raise overflow_error(
                f"the quad's normal (edge1 x edge2 = {format_vec(self.edge1)} x "
                f"{format_vec(self.edge2)})"
            )
        if nearly_parallel(self.edge1, self.edge2):
            raise scene_error("degenerate quad: edge1 and edge2 are parallel or zero")
        return self


class Rotation(SceneModel):
    """A right-handed rotation by ``angle`` degrees about ``axis`` through the world origin."""

    axis: Vec3
    angle: Float

    _check_axis = field_validator("axis")(_require_nonzero)


class Box(ObjectBase):
    """The box [min, max], then rotated about the world origin, then translated."""

    type: Literal["box"] = "box"
    min: Vec3
    max: Vec3
    rotate: Rotation | None = None
    translate: Vec3 = (0.0, 0.0, 0.0)

    @model_validator(mode="after")
    def _check_extent(self) -> Box:
        for k in range(3):
            if not self.min[k] < self.max[k]:
                raise scene_error(
                    f"min must be < max in every component: {AXES[k]} has "
                    f"min {self.min[k]:g} >= max {self.max[k]:g}"
                )
        return self


class Mesh(ObjectBase):
    """A triangle mesh, inline (``vertices`` + ``triangles``) or, from the CLI only, a file.

    Triangles are counter-clockwise seen from outside. Numeric checks (index range, degenerate
    triangles, closedness) are vectorized in ``load_scene``; use ``arrays()`` for the numbers: a
    million triangles stay as two numpy arrays, never as Python lists. A mesh read from ``path``
    keeps ``vertices``/``triangles`` at None and its ``path`` is cleared once loaded.
    """

    type: Literal["mesh"] = "mesh"
    vertices: list[Vec3] | None = Field(default=None, min_length=1)
    triangles: list[tuple[VertexIndex, VertexIndex, VertexIndex]] | None = Field(
        default=None, min_length=1
    )
    uvs: list[tuple[Float, Float]] | None = Field(default=None, min_length=1)
    """Texture coordinates (u, v), one per vertex (inline meshes; files give theirs)."""
    normals: list[Vec3] | None = Field(default=None, min_length=1)
    """Shading normals, one per vertex, interpolated across each triangle (inline meshes)."""
    path: str | None = None
    asset: AssetName | None = None
    """An uploaded mesh file (OBJ or PLY), ``"sha256:<hex>"``, instead of ``path``."""
    scale: PositiveFloat | tuple[PositiveFloat, PositiveFloat, PositiveFloat] | None = None
    """Placement (optional): scale (one number, or one per axis), then ``rotate``, then
    ``translate``, about the world origin, as a box is placed; the file or the inline vertices
    stay in the model's own coordinates."""
    rotate: Rotation | None = None
    translate: Vec3 | None = None

    _vertices_array: np.ndarray | None = PrivateAttr(default=None)
    _world_vertices: np.ndarray | None = PrivateAttr(default=None)
    _triangles_array: np.ndarray | None = PrivateAttr(default=None)
    _uvs_array: np.ndarray | None = PrivateAttr(default=None)
    _normals_array: np.ndarray | None = PrivateAttr(default=None)
    _world_normals: np.ndarray | None = PrivateAttr(default=None)
    _dropped_degenerate: int = PrivateAttr(default=0)
    _source_path: Path | None = PrivateAttr(default=None)

    _scale = field_validator("scale", mode="wrap")(union_error(
        "must be a number > 0, or a list of 3 numbers > 0 (one per axis)"))

    @field_validator("path")
    @classmethod
    def _check_path_allowed(cls, path: str | None, info: ValidationInfo) -> str | None:
        if path is not None:
            try:
                _path_allowed(path, info)
            except PydanticCustomError:
                raise scene_error(
                    "file paths are accepted only by the command line; send vertices and "
                    'triangles inline, or upload the file (POST /api/assets) and give "asset"'
                ) from None
        return path

    @model_validator(mode="after")
    def _check_source(self) -> Mesh:
        inline = self.vertices is not None or self.triangles is not None
        given = [name for name in ("path", "asset") if getattr(self, name) is not None]
        if len(given) > 1 or (inline and given):
            parts = (["vertices and triangles"] if inline else []) + given
            raise scene_error(
                f"give one of vertices and triangles, path or asset, not {' and '.join(parts)}"
            )
        if given and (self.uvs is not None or self.normals is not None):
            extra = " and ".join(f for f in ("uvs", "normals") if getattr(self, f) is not None)
            raise scene_error(f"{extra} belong to an inline mesh; a mesh file gives its own "
                              "(OBJ vt/vn, PLY u,v/nx,ny,nz)")
        if not given:
            if self.vertices is None and self.triangles is None:
                raise scene_error(
                    "a mesh needs vertices and triangles, or asset (or, from the CLI, path)"
                )
            if self.vertices is None:
                raise scene_error("triangles given without vertices")
            if self.triangles is None:
                raise scene_error("vertices given without triangles")
        return self

    @model_serializer(mode="wrap")
    def _serialize(self, handler: SerializerFunctionWrapHandler):  # no return annotation: keeps
        # the serialization JSON schema that of the model instead of "any".
        # A mesh read from a file serializes inline, so that the CLI can send a loaded scene to
        # the farm (whose API accepts no paths).
        # A mesh from an asset keeps its reference (whoever reads the scene can fetch it).
        data = handler(self)
        if (
            self.vertices is None
            and self.asset is None
            and self._vertices_array is not None
            and isinstance(data, dict)
        ):
            data["vertices"] = self._vertices_array.tolist()
            data["triangles"] = self._triangles_array.tolist()
            if self._uvs_array is not None:
                data["uvs"] = self._uvs_array.tolist()
            if self._normals_array is not None:
                data["normals"] = self._normals_array.tolist()
            data.pop("path", None)
        return data

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(vertices float64 (V, 3) in world coordinates, placed by ``scale``, ``rotate`` and
        ``translate``; triangles int64 (T, 3)), read-only and built once."""
        model, triangles = self.model_arrays()
        if self.scale is None and self.rotate is None and self.translate is None:
            return model, triangles
        if self._world_vertices is None:
            from renderer.geometry.transform import apply_linear, placement

            m, t = placement(self.scale, self.rotate, self.translate)
            with np.errstate(over="ignore", invalid="ignore"):  # load_scene names overflow
                world = apply_linear(model, m) + t
            world.flags.writeable = False
            self._world_vertices = world
        return self._world_vertices, triangles

    def _per_vertex(self, name: str, width: int) -> np.ndarray | None:
        """The inline per-vertex list ``name`` (uvs, normals) as a read-only float64 array, built
        once (a mesh read from a file has its array attached instead), or None."""
        attr = f"_{name}_array"
        if getattr(self, attr) is None and getattr(self, name) is not None:
            values = np.asarray(getattr(self, name), np.float64).reshape(-1, width)
            values.flags.writeable = False
            setattr(self, attr, values)
        return getattr(self, attr)

    def uv_array(self) -> np.ndarray | None:
        """Texture coordinates float64 (V, 2), or None when the mesh has none."""
        return self._per_vertex("uvs", 2)

    def normal_array(self) -> np.ndarray | None:
        """Shading normals float64 (V, 3) in world coordinates (unit; placed by the inverse
        transpose of the placement), or None when the mesh has none."""
        if self.model_normal_array() is None:
            return None
        if self._world_normals is None:
            normals = self._normals_array
            if self.scale is not None or self.rotate is not None:
                from renderer.geometry.transform import apply_linear, placement

                m, _ = placement(self.scale, self.rotate, self.translate)
                normals = apply_linear(normals, np.linalg.inv(m).T)  # (M⁻ᵀ n)ᵀ = nᵀ M⁻¹
            with np.errstate(invalid="ignore", divide="ignore"):
                normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
            normals.flags.writeable = False
            self._world_normals = normals
        return self._world_normals

    def model_normal_array(self) -> np.ndarray | None:
        """The shading normals as given (the model's coordinates, not normalized), or None."""
        return self._per_vertex("normals", 3)

    def _attach_attributes(self, uvs: np.ndarray | None, normals: np.ndarray | None) -> None:
        """Keep the texture coordinates and normals of a mesh read from a file."""
        self._uvs_array = None if uvs is None else np.ascontiguousarray(uvs, np.float64)
        self._normals_array = None if normals is None else np.ascontiguousarray(normals,
                                                                                np.float64)
        self._world_normals = None

    def model_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """``arrays()`` in the model's own coordinates, before placement."""
        if self._vertices_array is None:
            if self.vertices is None or self.triangles is None:
                raise ValueError("mesh has no geometry: load the scene with load_scene")
            # fromiter over the flattened tuples: 2-3x faster than np.asarray on a list of tuples.
            vertices = np.fromiter(
                chain.from_iterable(self.vertices), np.float64, 3 * len(self.vertices)
            )
            triangles = np.fromiter(
                chain.from_iterable(self.triangles), np.int64, 3 * len(self.triangles)
            )
            self._attach_arrays(vertices, triangles)
        return self._vertices_array, self._triangles_array

    def _attach_arrays(
        self,
        vertices: np.ndarray,
        triangles: np.ndarray,
        *,
        dropped_degenerate: int = 0,
        source_path: Path | None = None,
    ) -> None:
        """Keep the numeric arrays (load_scene calls this for meshes read from files)."""
        vertices = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
        triangles = np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3)
        vertices.flags.writeable = False
        triangles.flags.writeable = False
        self._vertices_array = vertices
        self._triangles_array = triangles
        self._world_vertices = None
        self._dropped_degenerate = dropped_degenerate
        if source_path is not None:
            self._source_path = source_path

    @property
    def dropped_degenerate(self) -> int:
        """Degenerate (zero-area) triangles dropped when the mesh was read from a file."""
        return self._dropped_degenerate

    @property
    def source_path(self) -> Path | None:
        """The file the mesh was read from, resolved; None for an inline mesh."""
        return self._source_path

    @property
    def num_triangles(self) -> int:
        if self._triangles_array is not None:
            return int(self._triangles_array.shape[0])
        return len(self.triangles or ())


Object = Annotated[Sphere | Quad | Box | Mesh, Field(discriminator="type")]

OBJECT_TYPES = ("sphere", "quad", "box", "mesh")


# --- Lights ---------------------------------------------------------------------------------------


class PointLight(SceneModel):
    type: Literal["point"] = "point"
    position: Vec3
    intensity: Colour
    """Radiant intensity, W/sr per channel."""


class DirectionalLight(SceneModel):
    type: Literal["directional"] = "directional"
    direction: Vec3
    """The direction the light travels (from the light towards the scene)."""
    irradiance: Colour
    """W/m² on a surface facing the light."""

    _check_direction = field_validator("direction")(_require_nonzero)


Light = Annotated[PointLight | DirectionalLight, Field(discriminator="type")]

LIGHT_TYPES = ("point", "directional")


# --- Environment (v1.1, "Light from an environment") ----------------------------------------------


class Environment(ImageModel):
    """A latitude–longitude image of linear radiance around the scene (``renderer.environment``):
    seen by every ray that escapes and sampled as a light. ``load_scene`` reads the image."""

    image: FileRef
    """EXR, PFM or Radiance ``.hdr``: a path (the command line) or ``{"asset": "sha256:…"}``."""
    scale: NonNegative = 1.0
    """Multiplies the image's radiance."""
    rotate: Rotation | None = None
    """Turns the environment about the world origin (a world direction d looks up the image at
    rotate⁻¹·d)."""

    _check_image = field_validator("image")(check_file_ref)
    _what: ClassVar[str] = "environment"


# --- Scene ----------------------------------------------------------------------------------------


class Scene(SceneModel):
    """A whole scene document. Load it with ``load_scene``, which adds the cross-checks."""

    camera: Camera
    film: Film
    render: RenderSettings = Field(default_factory=RenderSettings)
    background: Colour = (0.0, 0.0, 0.0)
    """Constant radiance of rays that escape; it lights the scene."""
    environment: Environment | None = None
    """An image of the radiance around the scene instead of ``background`` (v1.1)."""
    materials: dict[str, Material]
    objects: list[Object] = Field(min_length=1)
    lights: list[Light] = Field(default_factory=list)

    @field_validator("materials")
    @classmethod
    def _check_names(cls, materials: dict[str, Material]) -> dict[str, Material]:
        # A str field refuses a lone UTF-16 surrogate ("\ud800" in JSON: no Unicode text, which
        # no UTF-8 file or reply can hold); a dict key is not checked, so the names are here.
        for name in materials:
            try:
                name.encode("utf-8")
            except UnicodeEncodeError:
                shown = name.encode("utf-8", "backslashreplace").decode("utf-8")
                raise scene_error(
                    f"the material name {shown!r} is not Unicode text (it holds a lone UTF-16 "
                    "surrogate)"
                ) from None
        return materials
