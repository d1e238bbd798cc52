"""Spheres that no other surface enters (``renderer.geometry.shapes.spheres_alone``), and the walk
that asks such a sphere alone (``trace_path``).

The geometric test is checked on hand-built cases (a floor touching the sphere, a quad through
it, beside it, grazing it with an edge; nested, disjoint and overlapping spheres) and against the
distance to densely sampled points of random triangles and quads. The walk's shortcut must give
the sample buffers of the whole scene's query bit for bit, and a wrong flag must show in the
image (so the flag is what the walk reads).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from renderer.geometry.shapes import (
    QUAD,
    SPAWN_EPSILON,
    SPHERE,
    TRIANGLE,
    _enters_ball,
    prim_bounds,
    spheres_alone,
)
from renderer.render import render_buffer
from renderer.scene import load_scene
from renderer.scene.compile import compile_scene

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"


def _alone(prims, which=None):
    kind = np.array([k for k, _ in prims], np.int8)
    geo = np.zeros((len(prims), 9))
    for i, (_, g) in enumerate(prims):
        geo[i, :len(g)] = g
    lo, hi = prim_bounds(kind, geo)
    mask = np.ones(len(prims), bool) if which is None else np.asarray(which)
    return list(spheres_alone(kind, geo, lo, hi, mask))


BALL = (SPHERE, [0.0, -0.5, 0.0, 0.5])
FLOOR = (QUAD, [-1.0, -1.0, 1.0, 2.0, 0.0, 0.0, 0.0, 0.0, -2.0])  # y = -1, under the ball


def test_a_sphere_resting_on_a_floor_is_alone():
    assert _alone([BALL, FLOOR]) == [1, 0]


@pytest.mark.parametrize("depth, alone", [(0.1 * SPAWN_EPSILON, 1), (1e-6, 0), (0.2, 0)])
def test_a_floor_raised_into_the_sphere(depth, alone):
    raised = (QUAD, [-1.0, -1.0 + depth, 1.0, 2.0, 0.0, 0.0, 0.0, 0.0, -2.0])
    assert _alone([BALL, raised])[0] == alone


def test_quads_beside_through_and_grazing():
    # In the plane z = 0 through the centre, but beside the ball: alone
    beside = (QUAD, [0.6, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0])
    assert _alone([BALL, beside])[0] == 1
    # Through the centre: not alone
    through = (QUAD, [-0.2, -0.7, 0.0, 0.4, 0.0, 0.0, 0.0, 0.4, 0.0])
    assert _alone([BALL, through])[0] == 0
    # Its projection outside the quad, one edge 0.45 from the centre: not alone
    grazing = (QUAD, [0.3, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.35])
    assert _alone([BALL, grazing])[0] == 0
    # A small triangle wholly inside the ball: not alone
    tri = (TRIANGLE, [0.0, -0.5, 0.0, 0.1, 0.0, 0.0, 0.0, 0.1, 0.0])
    assert _alone([BALL, tri])[0] == 0


def test_spheres_nested_disjoint_and_overlapping():
    inner, outer = (SPHERE, [0.0, 0.0, 0.0, 0.5]), (SPHERE, [0.1, 0.0, 0.0, 1.0])
    assert _alone([inner, outer]) == [1, 0]  # the outer one's inside holds the inner surface
    a, b = (SPHERE, [0.0, 0.0, 0.0, 1.0]), (SPHERE, [2.5, 0.0, 0.0, 1.0])
    assert _alone([a, b]) == [1, 1]
    c = (SPHERE, [1.5, 0.0, 0.0, 1.0])
    assert _alone([a, c]) == [0, 0]
    assert _alone([a, b], which=[False, True]) == [0, 1]  # only the spheres asked about


def test_enters_ball_against_sampled_distances():
    """Against the least distance to 300² points of each primitive (its interior and edges),
    on random configurations whose distance is clear of r by more than the sampling's error."""
    rng = np.random.default_rng(7)
    s = np.linspace(0.0, 1.0, 300)
    a, b = np.meshgrid(s, s)
    checked = 0
    for _ in range(400):
        kind = QUAD if rng.random() < 0.5 else TRIANGLE
        geo = np.concatenate([rng.uniform(-1, 1, 3), rng.uniform(-1, 1, 3), rng.uniform(-1, 1, 3)])
        keep = np.ones_like(a, bool) if kind == QUAD else a + b <= 1.0
        pts = geo[0:3] + a[keep, None] * geo[3:6] + b[keep, None] * geo[6:9]
        c = rng.uniform(-1, 1, 3)
        dist = float(np.sqrt(((pts - c) ** 2).sum(axis=1)).min())
        r = float(rng.uniform(0.05, 1.5))
        step = 2.0 * float(np.linalg.norm(geo[3:6]) + np.linalg.norm(geo[6:9])) / 299
        if abs(dist - r) <= step:
            continue
        assert _enters_ball(kind, geo, c, r) == (dist < r), (kind, geo, c, r, dist)
        checked += 1
    assert checked > 300


def _compiled(name):
    return compile_scene(load_scene(json.loads((EXAMPLES / f"{name}.json").read_text())))


def _small(cs, flags=None):
    arrays = cs.arrays if flags is None else cs.arrays._replace(prim_alone=flags)
    return dataclasses.replace(cs, arrays=arrays, width=32, height=24)


@pytest.mark.parametrize("name", ["translucent_sphere", "chromatic_wax"])
def test_the_walk_inside_a_sphere_alone_is_the_whole_scenes_walk(name):
    """The wax sphere rests on the floor of a Cornell box: alone. Rendered with the flag and
    with it cleared (the whole scene asked at every step), the sample buffers are the same bit
    for bit."""
    cs = _compiled(name)
    assert cs.arrays.prim_alone.tolist() == [1 if k == SPHERE else 0
                                             for k in cs.arrays.prim_kind]
    fast = render_buffer(_small(cs), 16)
    slow = render_buffer(_small(cs, np.zeros_like(cs.arrays.prim_alone)), 16)
    for f in ("sum", "sum_sq", "count", "segments"):
        assert np.array_equal(getattr(fast, f), getattr(slow, f)), f


def test_a_wrong_flag_shows_in_the_image():
    """A quad through the wax sphere: not alone. Flagged alone anyway, the walk no longer sees
    the quad and the image changes: the flag is what the walk reads."""
    scene = json.loads((EXAMPLES / "translucent_sphere.json").read_text())
    scene["objects"].append({"type": "quad", "origin": [-0.3, -0.5, -0.3], "edge1": [0.6, 0, 0],
                             "edge2": [0, 0, 0.6], "material": "red"})
    cs = compile_scene(load_scene(scene))
    assert not cs.arrays.prim_alone.any()
    wrong = np.where(cs.arrays.prim_kind == SPHERE, 1, 0).astype(np.int8)
    right = render_buffer(_small(cs), 16)
    forced = render_buffer(_small(cs, wrong), 16)
    assert not np.array_equal(right.sum, forced.sum)
