"""``auto``'s rule against its own evidence: the committed chart data in docs/images/accuracy.

These tests render nothing. They fail when the rule (``BIAS_FLOOR``, ``choose_method``) and the
measured data that justify it (``python -m bench.accuracy`` → results.csv, auto.csv) disagree, so
a rule changed without the data, or data re-measured without the rule, cannot be committed.
"""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from bench.accuracy import suite, with_method
from renderer.materials.auto import (
    BIAS_FLOOR,
    REGIME_FLOOR,
    SUITE_CLASSES,
    auto_choice,
    scene_regimes,
)
from renderer.scene import load_scene

DATA = Path(__file__).resolve().parents[3] / "docs" / "images" / "accuracy"
# The suite of the issue: sphere in a Cornell box, backlit slab, concave mesh, thin shell, albedo
# 0.5 / 0.9 / 0.99 (bench/accuracy.py).
SUITE = {"translucent_sphere", "backlit_slab", "translucent_torus", "translucent_shell",
         "sphere_albedo_0.5", "sphere_albedo_0.9", "sphere_albedo_0.99"}


def _rows(name: str) -> list[dict]:
    with open(DATA / name, newline="") as f:
        return list(csv.DictReader(f))


def _largest_floor(rows: list[dict], method: str) -> float:
    mine = [r for r in rows if r["method"] == method]
    top = max(int(r["spp"]) for r in mine)
    return max(float(r["object_rel_mse"]) for r in mine if int(r["spp"]) == top)


def test_the_committed_data_cover_the_whole_suite():
    rows = _rows("results.csv")
    assert {r["scene"] for r in rows} == SUITE
    for method in BIAS_FLOOR:
        assert {r["scene"] for r in rows if r["method"] == method} == SUITE


@pytest.mark.parametrize("method", sorted(BIAS_FLOOR))
def test_every_floor_is_the_largest_measured_error_of_its_method(method):
    """BIAS_FLOOR is at least the method's largest object relMSE at its highest spp on the suite
    (else auto would promise an error the method does not reach somewhere), and not more than 2 %
    above it (rounding up; a floor far above the data would be a made-up number)."""
    measured = _largest_floor(_rows("results.csv"), method)
    assert measured <= BIAS_FLOOR[method] <= 1.02 * measured


@pytest.mark.parametrize("method", sorted(BIAS_FLOOR))
def test_every_regime_floor_is_the_largest_error_of_its_scenes(method):
    """REGIME_FLOOR[method][regime] is the largest object relMSE at the highest spp over the suite
    scenes of that regime (rounded up by at most 2 %), and the worst regime is BIAS_FLOOR."""
    rows = [r for r in _rows("results.csv") if r["method"] == method]
    top = {r["scene"]: max(int(x["spp"]) for x in rows if x["scene"] == r["scene"]) for r in rows}
    for regime in ("solid", "backlit", "mesh"):
        measured = max(float(r["object_rel_mse"]) for r in rows
                       if SUITE_CLASSES[r["scene"]] == regime and int(r["spp"]) == top[r["scene"]])
        assert measured <= REGIME_FLOOR[method][regime] <= 1.02 * measured, regime
    assert max(REGIME_FLOOR[method].values()) == BIAS_FLOOR[method]


def test_the_suite_scenes_are_classified_as_their_regimes():
    """scene_regimes puts each suite scene in its class: the spheres lit from above in front of
    the camera are solid, the slab with its lamp behind is backlit, the torus and the shell are
    meshes (both lit from the camera's side)."""
    assert set(SUITE_CLASSES) == SUITE
    expected = {"solid": frozenset(), "backlit": frozenset({"backlit"}),
                "mesh": frozenset({"mesh"})}
    for name, (scene, material) in suite().items():
        loaded = load_scene(with_method(scene, material, "auto", 1))
        objects = [o for o in loaded.objects if o.material == material]
        assert scene_regimes(loaded, objects) == expected[SUITE_CLASSES[name]], name


def test_auto_table_is_the_current_rule_and_auto_is_never_slower():
    """auto.csv records, per scene and target, auto's choice and the seconds that choice and
    volumetric take to reach the target on the measured curves. The choice must be what the rule
    says now, and wherever auto claims an approximation is good enough it must reach the target
    no later than volumetric."""
    rows = _rows("auto.csv")
    assert {r["scene"] for r in rows} == SUITE
    approximations = [r for r in rows if r["auto_method"] != "volumetric"]
    assert approximations, "no target in the table where auto picks an approximation"
    assert any(r["auto_method"] == "volumetric" for r in rows), "no fall-back target in the table"
    scenes = suite()
    for r in rows:
        scene, material = scenes[r["scene"]]
        d = with_method(scene, material, "auto", 1)
        d["render"]["target_error"] = float(r["target"])
        assert auto_choice(load_scene(d), material).method == r["auto_method"], r
        assert r["auto_read"] != "never", r
        # "tie": auto's time is only bounded by its first point (4 spp) and within 10 % of
        # volumetric's, so the curves cannot tell them apart (bench.accuracy._claim)
        assert r["claim_holds"] in ("yes", "tie"), r
        if r["claim_holds"] == "yes":
            assert float(r["auto_seconds"]) <= float(r["volumetric_seconds"]), r
        else:
            assert r["auto_read"] == "first point", r
            assert float(r["auto_seconds"]) <= 1.1 * float(r["volumetric_seconds"]), r
