"""bench.seed_workload's peer scenes: the seed boxes in the two materials Mitsuba 3 can draw."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.seed_workload import PEER_MATERIALS, SCENES, peer_scene
from renderer.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("name", SCENES)
@pytest.mark.parametrize("material", PEER_MATERIALS)
def test_peer_scene_redraws_only_the_single_scatter_boxes(name, material):
    scene = json.loads((ROOT / "examples" / f"{name}.json").read_text())
    peer = peer_scene(scene, material)
    assert peer["objects"] == scene["objects"] and peer["camera"] == scene["camera"]
    changed = {k for k, m in scene["materials"].items() if m.get("method") == "single_scatter"}
    assert changed == {"blue_box", "amber_box"}
    for key, mat in scene["materials"].items():
        if key not in changed:
            assert peer["materials"][key] == mat
            continue
        new = peer["materials"][key]
        assert new["albedo"] == mat["albedo"]
        if material == "diffuse":
            assert new == {"type": "diffuse", "albedo": mat["albedo"]}
        else:
            # the paper's boxes with every scattering order: same medium, an index-matched boundary
            assert (new["method"], new["ior"]) == ("volumetric", 1.0)
            assert (new["density"], new["g"]) == (mat["density"], mat["g"])
    assert scene["materials"]["blue_box"]["method"] == "single_scatter"  # the input is untouched
    load_scene(peer)  # a valid scene


@pytest.mark.mitsuba
@pytest.mark.parametrize("material", PEER_MATERIALS)
def test_mitsuba_accepts_the_peer_scenes(material):
    pytest.importorskip("mitsuba")
    from renderer.mitsuba_bridge import to_mitsuba_dict

    scene = json.loads((ROOT / "examples" / f"{SCENES[1]}.json").read_text())
    with pytest.raises(NotImplementedError):
        to_mitsuba_dict(scene, variant="scalar_rgb")  # why the peer needs other materials
    assert to_mitsuba_dict(peer_scene(scene, material), variant="scalar_rgb")
