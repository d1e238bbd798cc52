"""``method: "auto"``: the cheapest translucent method whose expected error meets the target.

The expected errors come from the speed/accuracy suite (``python -m bench.accuracy``;
docs/speed-accuracy.md): each approximation has a bias floor, the relative MSE over the object's
pixels that it keeps however many samples it takes. The largest floor measured over the suite
scenes of the regimes the scene is in (``REGIME_FLOOR``, ``scene_regimes``: solid, backlit, mesh;
the suite is the wax sphere, backlit slab, concave torus, thin shell and spheres at albedo 0.5,
0.9, 0.99; docs/images/accuracy/failures.md) is the method's expected error (the worst over the
whole suite, ``BIAS_FLOOR``, when the regimes are unknown). A method is chosen only if that is at
or below the scene's
``render.target_error`` (default ``DEFAULT_TARGET``), cheapest first; otherwise ``volumetric``,
the unbiased reference, which reaches any target given time.

Three regimes need no subsurface model at all, and are rendered as what they are:
- albedo 0 everywhere: nothing scatters, so the medium is exactly an absorbing glass (Beer–Lambert
  with σa = density): a ``dielectric``, no error;
- effectively clear: the optical size τ = density × size is so small that the fraction of light that
  scatters, ≈ albedo·τ, is below the target: a ``dielectric`` with σa = density·(1 − albedo) (the
  little scattered light is taken to go on forward);
- effectively opaque: 99 % of the light that enters leaves again within a pixel of where it went
  in (the radius of the ``diffusion`` method's profile that holds 99 % of its energy, against the
  width of a pixel at the object's distance from the camera) and within a tenth of the object's
  size: an opaque surface, a Fresnel coat over the semi-infinite medium's exact albedo
  (renderer/materials/opaque.py), whose error against ``volumetric`` on dense spheres is at
  most ``OPAQUE_ERROR``, and at most ``OPAQUE_ERROR_BY_ALBEDO``'s at the albedos and g measured
  (``opaque_error``; ``python -m bench.opaque``, docs/images/accuracy/opaque.csv).

A chromatic medium (σt per channel) is judged channel by channel (``channel_regimes``: each
channel absorbing, clear, opaque or translucent, as a grey medium at that channel's albedo and σt
would be), and takes the cheapest method acceptable in every channel (``choose_chromatic``): a
dielectric when each channel is absorbing or clear, the opaque surface when each is opaque, an
approximation when the channels are translucent, or translucent and opaque (nearly opaque in
blue, deep in red), and its floor, measured on the chromatic and mixed-regime scenes too
(``CHROMATIC_FLOOR``, ``MIXED_FLOOR``; ``python -m bench.accuracy --chromatic``), meets the target;
else ``volumetric``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from renderer.geometry.transform import camera_array, rotation_matrix
from renderer.materials.burley import burley_r_max
from renderer.materials.diffusion import diffusion_parameters

DEFAULT_TARGET = 0.01

# Largest object relMSE at 1024 spp over the suite (docs/images/accuracy/failures.md), rounded up,
# cheapest method first (the same file's timings: backlight < diffusion < single_scatter per
# sample). Set by the concave torus for backlight (0.473; 0.313 before the torus joined the suite,
# when auto took backlight at target 0.45, which it never reaches there) and single_scatter
# (2.2), by the backlit slab for diffusion (0.41). tests/renderer/materials/test_auto_evidence.py
# ties these numbers to the committed CSV.
BIAS_FLOOR = {"backlight": 0.474, "diffusion": 0.41, "single_scatter": 2.21}
# The same floors by regime: the largest over the suite scenes of each class (SUITE_CLASSES), so
# a scene pays only for the regimes it is in. "solid": convex spheres and boxes lit from the
# camera's side (the wax sphere, spheres of albedo 0.5, 0.9, 0.99); "backlit": the main light on
# the far side of the object (the jade slab); "mesh": meshes, which may be concave or thin (the
# torus, the shell). A scene's expected error is the largest floor of "solid" and of each other
# regime it is in. test_auto_evidence.py ties every number to results.csv.
REGIME_FLOOR = {
    "backlight": {"solid": 0.314, "backlit": 0.146, "mesh": 0.474},
    "diffusion": {"solid": 0.344, "backlit": 0.41, "mesh": 0.316},
    "single_scatter": {"solid": 0.236, "backlit": 0.377, "mesh": 2.21},
}
SUITE_CLASSES = {"translucent_sphere": "solid", "sphere_albedo_0.5": "solid",
                 "sphere_albedo_0.9": "solid", "sphere_albedo_0.99": "solid",
                 "backlit_slab": "backlit", "translucent_torus": "mesh",
                 "translucent_shell": "mesh"}
# Chromatic media (σt per channel), by the regimes of their channels (``channel_regimes``): the
# floors of the grey suite's scenes of each scene regime and of the chromatic suite's
# (docs/images/accuracy/chromatic/results.csv, ``python -m bench.accuracy --chromatic``; the
# approximations take each channel's own mean free path), the largest, rounded up. Every channel
# translucent: the chromatic wax and the skin1 sphere (solid), the chromatic jade slab (backlit).
# No chromatic mesh was measured: a chromatic mesh gets volumetric. test_auto_evidence.py ties
# every number to the CSVs.
CHROMATIC_FLOOR = {
    "backlight": {"solid": 0.314, "backlit": 0.197},
    "diffusion": {"solid": 0.344, "backlit": 0.514},
    "single_scatter": {"solid": 0.236, "backlit": 0.436},
}
# Translucent and opaque channels: the same, with the mixed-regime scenes as well (bench.accuracy
# MIXED: the chromatic wax and jade with blue at σt 1000, albedo 0.5, effectively opaque at
# 64×48). They raise only the backlit floors, and only a little (the mixed slab's backlight
# 0.198, single_scatter 0.4362): the opaque channel is the one an approximation gets right.
MIXED_FLOOR = {
    "backlight": {"solid": 0.314, "backlit": 0.199},
    "diffusion": {"solid": 0.344, "backlit": 0.514},
    "single_scatter": {"solid": 0.236, "backlit": 0.437},
}
CHROMATIC_CLASSES = {"chromatic_wax": "solid", "skin_preset": "solid",
                     "chromatic_slab": "backlit", "mixed_wax": "solid", "mixed_slab": "backlit"}
CHANNEL_REGIMES = ("absorbing", "clear", "opaque", "translucent")
# Largest object relMSE of the opaque surface against volumetric over the dense spheres of
# docs/images/accuracy/opaque.csv (tests/renderer/materials/test_opaque.py ties it to the CSV).
OPAQUE_ERROR = 0.00847
# The same at each albedo measured (over g 0 and 0.5 and both densities), rounded up: it grows
# with the albedo (the light's walk is longer, its exit spread wider), so an albedo between two
# takes the next one up's (opaque_error). test_opaque.py ties these to the CSV too.
OPAQUE_ERROR_BY_ALBEDO = ((0.3, 0.000788), (0.8, 0.00189), (0.95, 0.00326), (0.99, 0.00847))
# The largest g measured: beyond it (and beyond the largest albedo) the error is taken to be
# OPAQUE_ERROR, unmeasured (forward scattering raised it at every albedo measured)
OPAQUE_MEASURED_G = 0.5
OPAQUE_QUANTILE = 0.99  # of the profile's energy that must leave within a pixel


def opaque_error(albedo, g: float) -> float:
    """The opaque surface's expected error (object relMSE against ``volumetric``) for a medium of
    this ``albedo`` (one number or one per channel, the largest counts) and ``g``: the measured
    error at the smallest albedo measured at or above it (``OPAQUE_ERROR_BY_ALBEDO``, the
    largest over the g measured), ``OPAQUE_ERROR`` beyond the albedos or the g measured."""
    a = float(np.max(albedo))
    if abs(g) <= OPAQUE_MEASURED_G:
        for measured, error in OPAQUE_ERROR_BY_ALBEDO:
            if a <= measured:
                return min(error, OPAQUE_ERROR)
    return OPAQUE_ERROR


def format_rgb(v) -> str:
    return "/".join(f"{x:.3g}" for x in v)


@dataclass
class AutoChoice:
    method: str  # a translucent method, "dielectric" or "opaque"
    reason: str
    # the method's expected bias: its relMSE over the object's pixels with the noise gone (an
    # approximation's measured floor, the opaque limit's error; 0 for an exact method)
    expected_error: float


def describe_choice(reason: str, expected_error: float) -> str:
    """Why ``auto`` chose a method, as the CLI prints it and the job API reports it: the reason
    and the method's expected bias, which the samples' noise (what ``render.target_error``'s
    sampling brings down) comes on top of."""
    bias = ("none (unbiased: the error is the samples' noise alone)" if expected_error == 0.0
            else f"relMSE {expected_error:.3g} over the object's pixels (the samples' noise "
                 "comes on top)")
    return f"{reason}; expected bias {bias}"


def opaque_reach(albedo, density, g: float, ior: float) -> float:
    """How far from its entry point ``OPAQUE_QUANTILE`` of the light that enters leaves: the
    widest channel's diffusion profile radius holding that much of its energy (``density``: σt,
    one number or one per channel; each channel's radius from its own albedo and σt)."""
    _, d, _ = diffusion_parameters(albedo, density, g, ior)
    return max(float(burley_r_max(float(x), OPAQUE_QUANTILE)) for x in d)


def opaque_limit(footprint: float, size: float) -> float:
    """The reach below which a material is effectively opaque: a pixel, and a tenth of the
    object (no light through it, none around its edges)."""
    return min(footprint, 0.1 * size)


def expected_floor(method: str, regimes: frozenset[str] | None) -> float:
    """A method's expected bias floor in a scene of these regimes (None: unknown, the worst)."""
    if regimes is None:
        return BIAS_FLOOR[method]
    return max(REGIME_FLOOR[method][r] for r in {"solid", *regimes})


def channel_regimes(albedo, density, size: float, target: float, *, g: float = 0.0,
                    ior: float = 1.0, footprint: float = 0.0) -> tuple[str, ...]:
    """Each channel's regime (one of ``CHANNEL_REGIMES``), judged from that channel's own albedo
    and σt alone, as if the medium were grey at them: "absorbing" (albedo 0), "clear" (the
    scattered fraction albedo·σt·size at or below the target), "opaque" (``OPAQUE_QUANTILE`` of
    its light leaves within ``opaque_limit``: a pixel and a tenth of the object; only with a
    known ``footprint`` and the channel's ``opaque_error`` within the target), else
    "translucent"."""
    a = np.broadcast_to(np.asarray(albedo, dtype=np.float64), (3,))
    sigma_t = np.broadcast_to(np.asarray(density, dtype=np.float64), (3,))
    reach = None
    if footprint > 0.0 and a.max() > 0.0:
        _, d, _ = diffusion_parameters(a, sigma_t, g, ior)
        reach = [float(burley_r_max(float(x), OPAQUE_QUANTILE)) if opaque_error(a[k], g) <= target
                 else math.inf for k, x in enumerate(d)]
    out = []
    for k in range(3):
        if a[k] == 0.0:
            out.append("absorbing")
        elif a[k] * sigma_t[k] * size <= target:
            out.append("clear")
        elif reach is not None and reach[k] <= opaque_limit(footprint, size):
            out.append("opaque")
        else:
            out.append("translucent")
    return tuple(out)


def chromatic_floor(method: str, regimes: frozenset[str] | None,
                    mixed: bool) -> float | None:
    """A method's expected bias floor on a chromatic medium in a scene of these regimes:
    ``CHROMATIC_FLOOR`` (every channel translucent) or ``MIXED_FLOOR`` (translucent and opaque
    channels); None where no chromatic scene of a regime was measured (meshes, unknown)."""
    if regimes is None or not regimes <= {"solid", "backlit"}:
        return None
    table = MIXED_FLOOR if mixed else CHROMATIC_FLOOR
    return max(table[method][r] for r in {"solid", *regimes})


def cheapest_within(floors: dict[str, float], target: float, where: str,
                    kind: str) -> AutoChoice:
    """The first (cheapest) approximation whose floor meets the target, else ``volumetric``."""
    for method, floor in floors.items():
        if floor <= target:
            return AutoChoice(method, f"{where}: {kind} {floor:g} <= target {target:g}", floor)
    return AutoChoice("volumetric", f"{where}: no approximation's {kind} (lowest "
                      f"{min(floors.values()):g}) meets target {target:g}", 0.0)


def choose_method(albedo, density, size: float, target: float | None, *, g: float = 0.0,
                  ior: float = 1.0, footprint: float = 0.0,
                  regimes: frozenset[str] | None = None, rough: bool = False) -> AutoChoice:
    """The method ``auto`` renders a material with; ``density`` is σt, one number or one per
    channel; ``size`` is the smallest half-extent of the objects that use it (the radius of a
    sphere), ``footprint`` the width of a pixel at the nearest of them (0: unknown, never
    opaque), ``regimes`` the scene's (``scene_regimes``; None: unknown, every method's worst
    floor).

    A chromatic medium (σt differs between channels) is judged channel by channel
    (``choose_chromatic``). A rough boundary (``rough``) is rendered by ``volumetric`` (or,
    clear, by a rough glass): the approximations' floors and the opaque limit's error were
    measured with a smooth coat (diffuse_entry and diffusion render a rough one, unmeasured)."""
    target = DEFAULT_TARGET if target is None else target
    sigma_t = np.broadcast_to(np.asarray(density, dtype=np.float64), (3,))
    if len(set(sigma_t.tolist())) > 1:
        return choose_chromatic(albedo, sigma_t, size, target, g=g, ior=ior,
                                footprint=footprint, regimes=regimes, rough=rough)
    tau = float(sigma_t.max()) * size
    a = max(albedo)
    where = f"optical radius {tau:.3g}, albedo {a:.3g}"
    if a == 0.0:
        return AutoChoice("dielectric", f"{where}: nothing scatters, an absorbing glass is exact",
                          0.0)
    if a * tau <= target:
        return AutoChoice("dielectric", f"{where}: effectively clear, scattered fraction "
                          f"{a * tau:.3g} <= target {target:g}", a * tau)
    if rough:
        return AutoChoice("volumetric", f"{where}: a rough boundary (no approximation's floor "
                          "was measured behind a rough coat)", 0.0)
    error = opaque_error(albedo, g)
    if footprint > 0.0 and error <= target:
        reach = opaque_reach(albedo, sigma_t, g, ior)
        if reach <= opaque_limit(footprint, size):
            return AutoChoice("opaque", f"{where}: effectively opaque, {OPAQUE_QUANTILE:.0%} of "
                              f"the light leaves within {reach:.3g} of where it entered, under a "
                              f"pixel ({footprint:.3g}); measured error {error:g} <= target "
                              f"{target:g}", error)
    floors = {method: expected_floor(method, regimes) for method in BIAS_FLOOR}
    kind = "" if regimes is None else f" ({', '.join(sorted({'solid', *regimes}))})"
    return cheapest_within(floors, target, where, f"measured bias floor{kind}")


def choose_chromatic(albedo, sigma_t, size: float, target: float, *, g: float, ior: float,
                     footprint: float, regimes: frozenset[str] | None,
                     rough: bool) -> AutoChoice:
    """``choose_method`` for a chromatic medium: each channel in its regime
    (``channel_regimes``), then the cheapest method whose error is acceptable in every channel:

    - every channel absorbing or clear: a ``dielectric`` absorbing σa = σt·(1 − albedo) per
      channel (exact where albedo is 0; the scattered fraction, the largest albedo·σt·size, where
      clear);
    - a rough boundary: ``volumetric``;
    - every channel opaque: the ``opaque`` surface (``opaque_error`` at its largest albedo);
    - every channel translucent: an approximation whose floor over the chromatic suite and the
      grey suite's scenes of the scene's regimes (``CHROMATIC_FLOOR``) meets the target;
    - translucent and opaque channels (nearly opaque in blue, deep in red): the same, with the
      floors that include the mixed-regime scenes (``MIXED_FLOOR``);
    - otherwise ``volumetric``: a clear or absorbing channel beside a scattering one (the
      approximations fail on clear media, docs/speed-accuracy.md, failure map), a mesh (no
      chromatic mesh was measured), or no floor within the target."""
    a = np.broadcast_to(np.asarray(albedo, dtype=np.float64), (3,))
    kinds = channel_regimes(a, sigma_t, size, target, g=g, ior=ior, footprint=footprint)
    where = (f"chromatic, optical radius {format_rgb(sigma_t * size)}, albedo {format_rgb(a)}: "
             + ", ".join(f"{c} {k}" for c, k in zip("RGB", kinds, strict=True)))
    present = set(kinds)
    if present <= {"absorbing", "clear"}:
        scattered = float(np.max(a * sigma_t * size))
        if present == {"absorbing"}:
            return AutoChoice("dielectric", f"{where}: nothing scatters, an absorbing glass is "
                              "exact", 0.0)
        return AutoChoice("dielectric", f"{where}: every channel absorbing or effectively clear, "
                          f"scattered fraction {scattered:.3g} <= target {target:g}", scattered)
    if rough:
        return AutoChoice("volumetric", f"{where}: a rough boundary (no approximation's floor "
                          "was measured behind a rough coat)", 0.0)
    if present == {"opaque"}:
        error = opaque_error(a, g)
        return AutoChoice("opaque", f"{where}: every channel effectively opaque, under a pixel "
                          f"({footprint:.3g}); measured error {error:g} <= target "
                          f"{target:g}", error)
    if not present <= {"opaque", "translucent"}:
        return AutoChoice("volumetric", f"{where}: a clear or absorbing channel beside a "
                          "scattering one, where no approximation's floor was measured", 0.0)
    mixed = "opaque" in present
    floors = {m: chromatic_floor(m, regimes, mixed) for m in BIAS_FLOOR}
    if None in floors.values():
        return AutoChoice("volumetric", f"{where}: no chromatic scene of these regimes "
                          f"({', '.join(sorted(regimes or {'unknown'}))}) was measured", 0.0)
    kind = f"{'mixed' if mixed else 'chromatic'} floor ({', '.join(sorted({'solid', *regimes}))})"
    return cheapest_within(floors, target, where, f"measured {kind}")


def _object_half_extent(obj) -> float:
    """The smallest half-extent of an object's bounds (a sphere's radius): its optical size."""
    if obj.type == "sphere":
        return float(obj.radius)
    if obj.type == "box":
        return float(np.min(np.subtract(obj.max, obj.min))) / 2
    if obj.type == "quad":
        return 0.0
    verts, _ = obj.arrays()
    return float(np.min(verts.max(axis=0) - verts.min(axis=0))) / 2


def _bounding_sphere(obj) -> tuple[np.ndarray, float]:
    if obj.type == "sphere":
        return np.asarray(obj.center, dtype=np.float64), float(obj.radius)
    if obj.type == "box":

        lo, hi = np.asarray(obj.min, np.float64), np.asarray(obj.max, np.float64)
        c = (lo + hi) / 2
        if obj.rotate is not None:
            c = rotation_matrix(obj.rotate.axis, obj.rotate.angle) @ c
        return c + np.asarray(obj.translate, np.float64), float(np.linalg.norm(hi - lo)) / 2
    if obj.type == "quad":
        o, e1, e2 = (np.asarray(v, np.float64) for v in (obj.origin, obj.edge1, obj.edge2))
        return o + (e1 + e2) / 2, float(np.linalg.norm(e1 + e2)) / 2
    verts, _ = obj.arrays()
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    return (lo + hi) / 2, float(np.linalg.norm(hi - lo)) / 2


def pixel_footprint(scene, objects) -> float:
    """The height of one pixel at the nearest of ``objects`` (their bounding spheres), in scene
    units; 0 when the camera is inside one."""
    cam = scene.camera
    pos = np.asarray(cam.position, dtype=np.float64)
    dist = min((float(np.linalg.norm(c - pos)) - r for c, r in map(_bounding_sphere, objects)),
               default=0.0)
    return max(dist, 0.0) * 2 * math.tan(math.radians(cam.fov) / 2) / scene.film.height


def _light_centres(scene) -> list[np.ndarray]:
    """Where the scene's lights are: emitting objects' centres, point lights, and directional
    lights far along their reverse direction; the background lights from everywhere (none)."""
    out = [_bounding_sphere(o)[0] for o in scene.objects if getattr(o, "emission", None)
           and max(o.emission) > 0]
    for light in scene.lights or []:
        if light.type == "point":
            out.append(np.asarray(light.position, np.float64))
        elif light.type == "directional":
            out.append(-1e6 * np.asarray(light.direction, np.float64))
    return out


def scene_regimes(scene, objects) -> frozenset[str]:
    """The regimes of ``REGIME_FLOOR`` the material's ``objects`` are in: "mesh" if one is a
    mesh; "backlit" if a light is on the far side of one of them from the camera (the light's and
    the camera's directions from its centre more than 90° apart)."""
    regimes = set()
    if any(o.type == "mesh" for o in objects):
        regimes.add("mesh")
    cam = np.asarray(scene.camera.position, np.float64)
    for o in objects:
        c, _ = _bounding_sphere(o)
        if any(float(np.dot(light - c, cam - c)) < 0.0 for light in _light_centres(scene)):
            regimes.add("backlit")
    return frozenset(regimes)


def for_a_texture(choice: AutoChoice, *, rough: bool,
                  regimes: frozenset[str] | None) -> AutoChoice:
    """``choice`` (made on a textured albedo's mean) turned into a method a texture can colour:
    the texture colours a surface (the approximations'), not a medium. ``volumetric`` becomes the
    approximation with the lowest measured floor in the scene's regimes (``expected_floor``; the
    grey floors, chromatic or not), among those with a rough coat when the boundary is rough
    (diffusion alone: diffuse_entry has no measured floor, so ``auto`` never takes it); the
    ``opaque`` surface becomes ``diffusion``, whose profile follows the texture hit by hit (the
    opaque limit's albedo comes from walks at one colour). A ``dielectric`` is kept: a texture
    colours no glass, and ``load_scene`` refuses the scene, naming the albedo
    (``texture_refusal``)."""
    if choice.method not in ("volumetric", "opaque"):
        return choice
    if choice.method == "opaque":
        floor = expected_floor("diffusion", regimes)
        return AutoChoice("diffusion", f"{choice.reason}; a textured albedo: diffusion, whose "
                          "profile follows the texture at each hit, where the opaque limit "
                          f"takes one colour (measured floor {floor:g})", floor)
    candidates = ("diffusion",) if rough else tuple(BIAS_FLOOR)
    floors = {method: expected_floor(method, regimes) for method in candidates}
    best = min(floors, key=floors.__getitem__)
    coat = "with a rough coat " if rough else ""
    return AutoChoice(best, f"{choice.reason}; a textured albedo colours a surface, which "
                      f"volumetric has not: the approximation {coat}with the lowest measured "
                      f"floor, {best} {floors[best]:g}", floors[best])


def texture_refusal(choice: AutoChoice) -> str | None:
    """Why a textured albedo cannot be rendered as ``choice`` says (None: it can)."""
    if choice.method != "dielectric":
        return None
    return (f"a texture cannot colour this material: method auto renders it as a glass "
            f"({choice.reason}), which has no surface colour; give an RGB albedo, or a method "
            "(single_scatter, diffuse_entry, backlight, diffusion)")


def auto_choice(scene, name: str):
    """What ``method: "auto"`` picks for material ``name`` of a validated scene (cheap: no BVH),
    the same choice ``compile_scene`` renders: the farm's API reports it at submission. A
    textured albedo: the choice rests on its mean (``renderer.textures.texture_mean``), then
    ``for_a_texture``."""
    m = scene.materials[name]
    objects = [o for o in scene.objects if o.material == name]
    sizes = [_object_half_extent(o) for o in objects]
    regimes = scene_regimes(scene, objects)
    choice = choose_method(m.albedo_rgb, m.sigma_t, min(sizes) if sizes else 0.0,
                           scene.render.target_error, g=m.g, ior=m.ior,
                           footprint=pixel_footprint(scene, objects),
                           regimes=regimes, rough=m.roughness > 0.0)
    if getattr(m.albedo, "type", None) in ("bitmap", "checkerboard"):
        choice = for_a_texture(choice, rough=m.roughness > 0.0, regimes=regimes)
    return choice


# Rays at most for ``frame_share`` (pixel centres on a grid of every k-th pixel beyond it), and
# its ray-sphere tests at most (fewer rays where there are many objects: a job's every frame
# asks it at submission)
SHARE_RAYS = 65536
SHARE_TESTS = 1 << 24


def frame_share(scene, objects) -> float:
    """The share of the film's pixels that may see one of ``objects``: an upper bound of the
    pixels they cover, cheap (no BVH). A pixel counts when the ray through its centre passes
    within half its diagonal (as an angle, the film's centre pixel's, the largest) of an
    object's bounding sphere: every pixel the sphere's silhouette touches, so an object smaller
    than a pixel still counts; occlusion and the bounding sphere's slack only add to it. Beyond
    ``SHARE_RAYS`` pixels, one ray a block of k×k pixels (at the film's edges, the block's
    pixels that are on it), widened by half the block's diagonal, with fewer rays where
    ``SHARE_TESTS`` would be passed (coarser, still a bound). 1 where the camera is inside a
    bounding sphere."""
    if not objects:
        return 0.0
    w, h = scene.film.width, scene.film.height
    cam = camera_array(scene.camera, w, h)
    pos, forward, right, up, tan_half = cam[0:3], cam[3:6], cam[6:9], cam[9:12], float(cam[12])
    rays = max(1024, min(SHARE_RAYS, SHARE_TESTS // len(objects)))
    k = max(1, math.ceil(math.sqrt(w * h / rays)))
    # (the render's camera_ray through each block's centre; a block's pixels on the film)
    x0, y0 = np.arange(0, w, k), np.arange(0, h, k)
    bw, bh = np.minimum(k, w - x0), np.minimum(k, h - y0)
    xs = (2.0 * (x0 + bw / 2.0) / w - 1.0) * tan_half * (w / h)
    ys = (1.0 - 2.0 * (y0 + bh / 2.0) / h) * tan_half
    d = (forward[None, None, :] + xs[None, :, None] * right[None, None, :]
         + ys[:, None, None] * up[None, None, :])
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    # a pixel's angle is largest at the film's centre: 2 atan(tan_half / h) across; half a
    # block's diagonal
    widen = k * math.sqrt(2.0) * math.atan(tan_half / h)
    spheres = [_bounding_sphere(o) for o in objects]
    centres = np.array([c for c, _ in spheres], np.float64) - pos
    radii = np.array([r for _, r in spheres], np.float64)
    dist = np.linalg.norm(centres, axis=1)
    if (dist <= radii).any():
        return 1.0
    # a ray sees a sphere when its angle to the centre is within the sphere's angular radius
    # and the widening: its cosine at least the cosine of their sum (all in one product a
    # block of spheres)
    toward = centres / dist[:, None]
    least = np.cos(np.minimum(np.arcsin(radii / dist) + widen, math.pi))
    flat = d.reshape(-1, 3)
    seen = np.zeros(len(flat), bool)
    for i in range(0, len(spheres), 64):
        # (the products written out, not ``@``: a matrix product runs on the BLAS library's
        # threads, which spin after it and take the cores from the render that follows)
        block = toward[i:i + 64]
        cos = (flat[:, 0:1] * block[:, 0] + flat[:, 1:2] * block[:, 1]
               + flat[:, 2:3] * block[:, 2])
        seen |= (cos >= least[i:i + 64]).any(axis=1)
    weight = (bh[:, None] * bw[None, :]).ravel()
    return float(weight[seen].sum()) / (w * h)


def frame_bias(scene, choices: dict | None = None) -> float:
    """The bias ``auto``'s models add to the frame's relMSE, at most: over the materials it
    renders with a biased model (``AutoChoice.expected_error`` > 0, their measured relMSE over
    the object's pixels), Σ expected_error × ``frame_share`` of the material's objects, at most
    the largest of them. ``render.target_error`` bounds the frame's relMSE, the samples' noise
    and this together: the loop aims the noise at the target less it
    (``renderer.film.adaptive.noise_target``). A method the scene names is the scene's choice,
    and its bias is not counted. ``choices``: ``auto_choices(scene)``, where already made."""
    choices = auto_choices(scene) if choices is None else choices
    total = 0.0
    largest = 0.0
    for name, choice in choices.items():
        if choice.expected_error > 0.0:
            objects = [o for o in scene.objects if o.material == name]
            total += choice.expected_error * frame_share(scene, objects)
            largest = max(largest, choice.expected_error)
    return min(total, largest)


def auto_choices(scene) -> dict:
    """``auto_choice`` for every translucent material with method auto."""
    return {name: auto_choice(scene, name) for name, m in scene.materials.items()
            if m.type == "translucent" and m.method == "auto"}
