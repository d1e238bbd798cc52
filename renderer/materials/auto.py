"""``method: "auto"``: the cheapest translucent method whose expected error meets the target.

The expected errors come from the speed/accuracy suite (``python -m bench.accuracy``;
docs/speed-accuracy.md): each approximation has a bias floor, the relative MSE over the object's
pixels that it keeps however many samples it takes. The largest floor measured over the suite
(wax sphere, backlit slab, concave torus, thin shell, spheres at albedo 0.5, 0.9, 0.99;
docs/images/accuracy/failures.md) is
the method's expected error. A method is chosen only if that is at or below the scene's
``render.target_error`` (default ``DEFAULT_TARGET``), cheapest first; otherwise ``volumetric``,
the unbiased reference, which reaches any target given time.

Two regimes need no subsurface model at all, and are rendered as what they are:
- albedo 0 everywhere: nothing scatters, so the medium is exactly an absorbing glass (Beer–Lambert
  with σa = density): a ``dielectric``, no error;
- effectively clear: the optical size τ = density × size is so small that the fraction of light that
  scatters, ≈ albedo·τ, is below the target: a ``dielectric`` with σa = density·(1 − albedo) (the
  little scattered light is taken to go on forward).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DEFAULT_TARGET = 0.01

# Largest object relMSE at 1024 spp over the suite (docs/images/accuracy/failures.md), rounded up,
# cheapest method first (the same file's timings: backlight < diffusion < single_scatter per
# sample). Set by the concave torus for backlight (0.473; 0.313 before the torus joined the suite,
# when auto took backlight at target 0.45, which it never reaches there) and single_scatter
# (2.2), by the backlit slab for diffusion (0.41). tests/renderer/materials/test_auto_evidence.py
# ties these numbers to the committed CSV.
BIAS_FLOOR = {"backlight": 0.474, "diffusion": 0.41, "single_scatter": 2.21}


@dataclass
class AutoChoice:
    method: str  # a translucent method, or "dielectric"
    reason: str
    expected_error: float


def choose_method(albedo, density: float, size: float, target: float | None) -> AutoChoice:
    """The method ``auto`` renders a material with; ``size`` is the smallest half-extent of the
    objects that use it (the radius of a sphere)."""
    target = DEFAULT_TARGET if target is None else target
    tau = density * size
    a = max(albedo)
    where = f"optical radius {tau:.3g}, albedo {a:.3g}"
    if a == 0.0:
        return AutoChoice("dielectric", f"{where}: nothing scatters, an absorbing glass is exact",
                          0.0)
    if a * tau <= target:
        return AutoChoice("dielectric", f"{where}: effectively clear, scattered fraction "
                          f"{a * tau:.3g} <= target {target:g}", a * tau)
    for method, floor in BIAS_FLOOR.items():
        if floor <= target:
            return AutoChoice(method, f"{where}: measured bias floor {floor:g} <= target "
                              f"{target:g}", floor)
    return AutoChoice("volumetric", f"{where}: no approximation's measured bias floor (lowest "
                      f"{min(BIAS_FLOOR.values()):g}) meets target {target:g}", 0.0)


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


def auto_choice(scene, name: str):
    """What ``method: "auto"`` picks for material ``name`` of a validated scene (cheap: no BVH),
    the same choice ``compile_scene`` renders: the farm's API reports it at submission."""
    m = scene.materials[name]
    sizes = [_object_half_extent(o) for o in scene.objects if o.material == name]
    return choose_method(m.albedo, m.density, min(sizes) if sizes else 0.0,
                         scene.render.target_error)


def auto_choices(scene) -> dict:
    """``auto_choice`` for every translucent material with method auto."""
    return {name: auto_choice(scene, name) for name, m in scene.materials.items()
            if m.type == "translucent" and m.method == "auto"}
