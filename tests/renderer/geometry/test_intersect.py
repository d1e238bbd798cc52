"""Ray–shape intersection (renderer/geometry/shapes.py), the BVH (renderer/geometry/bvh.py) and
the flat search of small scenes (renderer/geometry/flat.py).

Shapes are checked against hand-computed hits and, for spheres, against the roots of
|o + t d − c|² = r² solved in 60-digit decimal arithmetic from the exact values of the float
inputs. The BVH is checked against brute force: the same intersection routine run over every
primitive must give exactly the same closest primitive and the same t (bit for bit: both call
``intersect_prim`` on the same numbers), and ``occluded`` must agree with it for any t_max. So is
the flat search, whose vector loop repeats the planar test's arithmetic.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
from decimal import Decimal, getcontext
from pathlib import Path

import numpy as np
import pytest

from renderer.geometry.bvh import (
    BVH_WIDTH,
    MAX_LEAF,
    STACK_SIZE,
    build_bvh,
    intersect_closest,
    occluded,
    stack_size,
    traversal_stack,
    widen_bvh,
)
from renderer.geometry.flat import (
    FLAT_MAX,
    FLAT_MIN_COLUMNS,
    FLAT_PAD,
    FLAT_ROWS,
    flat_geometry,
    flat_order,
    vector_pad,
)
from renderer.geometry.shapes import (
    INF,
    QUAD,
    SPHERE,
    TRIANGLE,
    intersect_parallelogram,
    intersect_prim,
    intersect_sphere,
    prim_bounds,
    surface_point,
)
from renderer.jit import alloc_kernel
from renderer.render import render_tile
from renderer.scene import load_scene
from renderer.scene.compile import compile_scene

# --- reference: exact sphere roots ---------------------------------------------------------------


def sphere_roots(o, d, c, r) -> tuple[float, float] | None:
    """Both roots t0 ≤ t1 of |o + t d − c|² = r², from the exact float inputs in 60 digits."""
    getcontext().prec = 60
    o, d, c = ([Decimal(float(x)) for x in v] for v in (o, d, c))
    f = [oi - ci for oi, ci in zip(o, c, strict=True)]
    a = sum(x * x for x in d)
    b = sum(x * y for x, y in zip(d, f, strict=True))
    cc = sum(x * x for x in f) - Decimal(float(r)) ** 2
    disc = b * b - a * cc
    if disc < 0:
        return None
    s = disc.sqrt()
    return float((-b - s) / a), float((-b + s) / a)


def unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def vec(v) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


# --- spheres --------------------------------------------------------------------------------------

SPH = np.array([1.0, 2.0, 3.0, 2.0, 0, 0, 0, 0, 0])  # centre (1, 2, 3), radius 2


def test_sphere_from_outside_inside_and_behind():
    t, _, _ = intersect_sphere((1.0, 2.0, -7.0), (0.0, 0.0, 1.0), SPH)
    assert t == 8.0  # enters at z = 1
    t, _, _ = intersect_sphere((1.0, 2.0, -7.0), (0.0, 0.0, 2.0), SPH)
    assert t == 4.0  # d need not be unit: t is in units of |d|
    t, _, _ = intersect_sphere((1.5, 2.0, 3.0), (1.0, 0.0, 0.0), SPH)
    assert t == 1.5  # from inside: the far side
    t, _, _ = intersect_sphere((1.5, 2.0, 3.0), (-1.0, 0.0, 0.0), SPH)
    assert t == 2.5
    t, _, _ = intersect_sphere((1.0, 2.0, 3.0), (0.0, -1.0, 0.0), SPH)
    assert t == 2.0  # from the centre
    assert intersect_sphere((1.0, 2.0, 10.0), (0.0, 0.0, 1.0), SPH)[0] == INF  # behind
    assert intersect_sphere((3.0001, 2.0, -7.0), (0.0, 0.0, 1.0), SPH)[0] == INF  # passes by
    assert intersect_sphere((2.9999, 2.0, -7.0), (0.0, 0.0, 1.0), SPH)[0] < INF  # grazes


def test_sphere_against_exact_roots(rng):
    # Random rays from inside and outside, unnormalized directions: t is the smallest positive root.
    for _ in range(300):
        c = rng.uniform(-5, 5, 3)
        r = rng.uniform(0.1, 3.0)
        o = rng.uniform(-8, 8, 3)
        d = rng.normal(size=3) * rng.uniform(0.1, 10.0)
        if rng.random() < 0.5:  # aim near the sphere so that most rays hit
            d = (c + rng.normal(size=3) * r - o) * rng.uniform(0.1, 10.0)
        t, _, _ = intersect_sphere(vec(o), vec(d), np.array([*c, r, 0, 0, 0, 0, 0]))
        roots = sphere_roots(o, d, c, r)
        positive = [x for x in (roots or ()) if x > 0.0]
        if not positive:
            assert t == INF
        else:
            assert t == pytest.approx(min(positive), rel=1e-12)


@pytest.mark.parametrize("h", [0.0, 0.5, 0.9, 0.999])
def test_far_tiny_sphere(h):
    # A radius-1e-3 sphere seen from 1e6 away, the ray passing at h·r from its centre. The naive
    # discriminant b² − c cancels 1e12 against 1e12 − 1e-6 and loses the sphere entirely; the
    # Ray Tracing Gems form keeps t exact to 1e-12 relative (1e-6 absolute, 1/1000 of the radius).
    # 1e-12 rather than the 1e-9 one might allow: 1e-9 of 1e6 is the radius itself, which would
    # not tell the near side of the sphere from the far side.
    r = 1e-3
    c = np.array([0.3, -0.2, 0.1])
    axis = unit([0.36, -0.48, 0.8])
    perp = unit(np.cross(axis, [1.0, 0.0, 0.0]))
    o = c - 1e6 * axis
    d = (c + h * r * perp) - o  # unnormalized, |d| ≈ 1e6
    geo = np.array([*c, r, 0, 0, 0, 0, 0])
    t, u, v = intersect_sphere(vec(o), vec(d), geo)
    t0, _ = sphere_roots(o, d, c, r)
    assert t == pytest.approx(t0, rel=1e-12)
    p, n = surface_point(SPHERE, geo, vec(o), vec(d), t, u, v)
    assert np.linalg.norm(np.asarray(p) - c) == pytest.approx(r, rel=1e-9)
    assert np.linalg.norm(n) == pytest.approx(1.0, abs=1e-15)
    assert np.dot(n, d) < 0.0  # the near side, facing the ray
    # A ray passing 1 % outside the radius misses.
    d_miss = (c + 1.01 * r * perp) - o
    assert intersect_sphere(vec(o), vec(d_miss), geo)[0] == INF


def test_sphere_surface_point_normal():
    for o, d in (((1.0, 2.0, -7.0), (0.1, 0.05, 1.0)), ((1.5, 2.0, 3.0), (0.3, -0.4, 0.2))):
        t, u, v = intersect_sphere(o, d, SPH)
        p, n = surface_point(SPHERE, SPH, o, d, t, u, v)
        hit = np.asarray(o) + t * np.asarray(d)
        np.testing.assert_allclose(p, hit, atol=1e-14)
        np.testing.assert_allclose(n, (hit - SPH[0:3]) / SPH[3], atol=1e-14)  # outward, unit


# --- quads and triangles --------------------------------------------------------------------------

PLANAR = np.array([1.0, 1.0, 1.0, 2.0, 0.5, 0.0, 0.3, 1.0, 0.8])  # origin, e1, e2 (tilted)
OFF = unit([0.2, -0.9, 0.6])  # the side rays come from (either side of the plane works)


def point(s, t) -> np.ndarray:
    return PLANAR[0:3] + s * PLANAR[3:6] + t * PLANAR[6:9]


@pytest.mark.parametrize("is_triangle", [False, True])
@pytest.mark.parametrize("side", [1.0, -1.0])
def test_planar_hit_parameters(is_triangle, side):
    # A ray aimed at origin + s·e1 + t·e2 hits at t = 1 (d = target − o) with (u, v) = (s, t),
    # from either side: the shapes are two-sided for intersection. (Points exactly on an edge may
    # round either way and are left out.)
    for s, t in ((0.3, 0.6), (0.1, 0.1), (0.45, 0.5), (0.01, 0.5), (0.7, 0.01)):
        q = point(s, t)
        o = q + side * 3.0 * OFF
        th, u, v = intersect_parallelogram(vec(o), vec(q - o), PLANAR, is_triangle)
        assert th == pytest.approx(1.0, rel=1e-14)
        assert u == pytest.approx(s, abs=1e-14)
        assert v == pytest.approx(t, abs=1e-14)


def test_planar_inside_and_outside():
    # (s, t) inside the parallelogram but past the diagonal: a quad hit, a triangle miss.
    for s, t, quad_hit, tri_hit in ((0.6, 0.6, True, False), (0.9, 0.05, True, True),
                                    (1.05, 0.5, False, False), (-0.05, 0.5, False, False),
                                    (0.5, 1.05, False, False), (0.5, -0.05, False, False)):
        q = point(s, t)
        o = q + 3.0 * OFF
        assert (intersect_prim(QUAD, vec(o), vec(q - o), PLANAR)[0] < INF) == quad_hit, (s, t)
        assert (intersect_prim(TRIANGLE, vec(o), vec(q - o), PLANAR)[0] < INF) == tri_hit, (s, t)


def test_planar_parallel_and_backward_rays():
    o = point(0.3, 0.3) + 2.0 * OFF
    for kind in (QUAD, TRIANGLE):
        # parallel to the plane (d along an edge): det = 0, a miss, not a division by zero
        assert intersect_prim(kind, vec(o), vec(PLANAR[3:6]), PLANAR)[0] == INF
        assert intersect_prim(kind, vec(point(0.3, 0.3)), vec(PLANAR[6:9]), PLANAR)[0] == INF
        # pointing away from the plane: the hit would be at t < 0
        assert intersect_prim(kind, vec(o), vec(OFF), PLANAR)[0] == INF


def test_triangle_barycentrics_and_normals(rng):
    for _ in range(200):
        b1, b2 = rng.dirichlet([1.0, 1.0, 1.0])[:2]
        q = point(b1, b2)
        o = q + rng.uniform(0.5, 5.0) * unit(rng.normal(size=3))
        t, u, v = intersect_prim(TRIANGLE, vec(o), vec(q - o), PLANAR)
        if t == INF:  # only a ray (almost) in the plane may miss
            assert abs(np.dot(unit(q - o), unit(np.cross(PLANAR[3:6], PLANAR[6:9])))) < 1e-3
            continue
        assert (u, v) == (pytest.approx(b1, abs=1e-12), pytest.approx(b2, abs=1e-12))
        for kind in (TRIANGLE, QUAD):
            p, n = surface_point(kind, PLANAR, vec(o), vec(q - o), t, u, v)
            np.testing.assert_allclose(p, q, atol=1e-13)
            np.testing.assert_allclose(n, unit(np.cross(PLANAR[3:6], PLANAR[6:9])), atol=1e-15)


# --- BVH ------------------------------------------------------------------------------------------


@alloc_kernel
def _brute_closest(prim_kind, prim_geo, o, d, t_max):
    """The closest hit over all primitives, in index order, with the BVH's strict t < best rule."""
    best_t = t_max
    best = -1
    best_u = best_v = 0.0
    for k in range(prim_kind.shape[0]):
        t, u, v = intersect_prim(prim_kind[k], o, d, prim_geo[k])
        if t < best_t:
            best_t, best, best_u, best_v = t, k, u, v
    if best < 0:
        return INF, -1, 0.0, 0.0
    return best_t, best, best_u, best_v


@alloc_kernel
def _compare_many(bvh, prim_kind, prim_geo, origins, dirs, t_max_factor):
    """(t, prim, u, v) of the BVH and of brute force for every ray, and occluded() against a
    t_max of t_max_factor × the brute-force t (inf when the ray misses)."""
    bvh_lo, bvh_hi, bvh_child, bvh_count, flat = bvh
    m = origins.shape[0]
    res = np.empty((m, 2, 4))
    occ = np.empty((m, 2), np.bool_)
    stack = traversal_stack(STACK_SIZE)
    for i in range(m):
        o = (origins[i, 0], origins[i, 1], origins[i, 2])
        d = (dirs[i, 0], dirs[i, 1], dirs[i, 2])
        t, p, u, v = intersect_closest(bvh_lo, bvh_hi, bvh_child, bvh_count, flat, prim_kind,
                                       prim_geo, o, d, np.inf, stack)
        tb, pb, ub, vb = _brute_closest(prim_kind, prim_geo, o, d, np.inf)
        res[i, 0, 0], res[i, 0, 1], res[i, 0, 2], res[i, 0, 3] = t, p, u, v
        res[i, 1, 0], res[i, 1, 1], res[i, 1, 2], res[i, 1, 3] = tb, pb, ub, vb
        t_max = tb * t_max_factor[i] if pb >= 0 else np.inf
        occ[i, 0] = occluded(bvh_lo, bvh_hi, bvh_child, bvh_count, flat, prim_kind, prim_geo, o,
                             d, t_max, stack)
        occ[i, 1] = _brute_closest(prim_kind, prim_geo, o, d, t_max)[1] >= 0
    return res, occ


def random_scene(rng, n_tri=5000, n_sph=150, n_quad=150):
    """Random triangles, spheres and quads in [−10, 10]³, of sizes 0.05 to 2."""
    tri = np.zeros((n_tri, 9))
    tri[:, 0:3] = rng.uniform(-10, 10, (n_tri, 3))
    tri[:, 3:9] = rng.normal(size=(n_tri, 6)) * rng.uniform(0.05, 1.0, (n_tri, 1))
    sph = np.zeros((n_sph, 9))
    sph[:, 0:3] = rng.uniform(-10, 10, (n_sph, 3))
    sph[:, 3] = rng.uniform(0.05, 1.0, n_sph)
    quad = np.zeros((n_quad, 9))
    quad[:, 0:3] = rng.uniform(-10, 10, (n_quad, 3))
    quad[:, 3:9] = rng.normal(size=(n_quad, 6)) * rng.uniform(0.05, 1.0, (n_quad, 1))
    kind = np.concatenate([np.full(n_tri, TRIANGLE), np.full(n_sph, SPHERE),
                           np.full(n_quad, QUAD)]).astype(np.int8)
    geo = np.concatenate([tri, sph, quad])
    perm = rng.permutation(len(kind))  # kinds interleaved, as in a real scene
    return kind[perm], np.ascontiguousarray(geo[perm])


def build_binary(kind, geo):
    """The binary BVH's node arrays and the primitives' order."""
    lo, hi = prim_bounds(kind, geo)
    *nodes, order = build_bvh(lo, hi)
    return tuple(nodes), order


NO_FLAT = np.zeros((FLAT_ROWS, 0))


def build(kind, geo):
    """The wide BVH the traversal walks (with no flat store, which would take precedence) and the
    primitives in BVH order, as renderer/scene/compile.py packs a large scene."""
    nodes, order = build_binary(kind, geo)
    wide = widen_bvh(*nodes)[:4]
    return (*wide, NO_FLAT), order, kind[order], np.ascontiguousarray(geo[order])


def build_flat(kind, geo):
    """A small scene as compile_scene packs it: no tree, the primitives by column, spheres
    first."""
    order = flat_order(kind)
    kind, geo = kind[order], np.ascontiguousarray(geo[order])
    empty_tree = (np.zeros((0, 3, BVH_WIDTH)), np.zeros((0, 3, BVH_WIDTH)),
                  np.zeros((0, BVH_WIDTH), np.int32), np.zeros((0, BVH_WIDTH), np.int32))
    return (*empty_tree, flat_geometry(kind, geo)), order, kind, geo


def random_rays(rng, m):
    origins = rng.uniform(-12, 12, (m, 3))
    dirs = rng.normal(size=(m, 3))
    # Axis-aligned rays (zero direction components: infinite slopes in the slab test) and rays
    # from outside the scene aimed at its middle.
    k = m // 10
    axes = np.eye(3)[rng.integers(0, 3, k)] * rng.choice([-1.0, 1.0], (k, 1))
    dirs[:k] = axes
    origins[k:2 * k] = unit_rows(rng.normal(size=(k, 3))) * 30.0
    dirs[k:2 * k] = rng.uniform(-5, 5, (k, 3)) - origins[k:2 * k]
    return origins, dirs


def unit_rows(a):
    return a / np.linalg.norm(a, axis=1, keepdims=True)


def check_against_brute_force(rng, kind, geo, n_rays):
    bvh, order, prim_kind, prim_geo = build(kind, geo)
    origins, dirs = random_rays(rng, n_rays)
    factors = rng.uniform(0.5, 1.5, n_rays)
    res, occ = _compare_many(bvh, prim_kind, prim_geo, origins, dirs, factors)
    hit = res[:, 1, 1] >= 0
    assert 0.2 < hit.mean() < 0.98  # both hits and misses are exercised
    np.testing.assert_array_equal(res[:, 0, 1], res[:, 1, 1])  # the same primitive
    np.testing.assert_array_equal(res[:, 0, 0], res[:, 1, 0])  # the same t, exactly
    np.testing.assert_array_equal(res[:, 0, 2:], res[:, 1, 2:])  # the same (u, v)
    np.testing.assert_array_equal(occ[:, 0], occ[:, 1])
    assert 0 < occ[:, 0].sum() < n_rays
    return bvh, order


def test_bvh_matches_brute_force(rng):
    kind, geo = random_scene(rng)
    check_against_brute_force(rng, kind, geo, 2000)


def test_bvh_structure(rng):
    kind, geo = random_scene(rng)
    lo, hi = prim_bounds(kind, geo)
    bvh, order = build_binary(kind, geo)
    node_lo, node_hi, node_offset, node_count = bvh
    n = len(kind)
    np.testing.assert_array_equal(np.sort(order), np.arange(n))  # a permutation

    # Walk the tree from the root: every node is reached once, every primitive lies in exactly
    # one leaf, and every box contains what is below it.
    covered = np.zeros(n, np.int64)
    seen = np.zeros(len(node_count), np.int64)
    stack = [0]
    while stack:
        i = stack.pop()
        seen[i] += 1
        if node_count[i] > 0:
            assert node_count[i] <= MAX_LEAF
            idx = order[node_offset[i]:node_offset[i] + node_count[i]]
            covered[node_offset[i]:node_offset[i] + node_count[i]] += 1
            assert np.all(node_lo[i] <= lo[idx]) and np.all(hi[idx] <= node_hi[i])
        else:
            for child in (i + 1, node_offset[i]):
                assert i < child < len(node_count)
                assert np.all(node_lo[i] <= node_lo[child])
                assert np.all(node_hi[child] <= node_hi[i])
                stack.append(child)
    np.testing.assert_array_equal(covered, 1)
    np.testing.assert_array_equal(seen, 1)


def wide_leaves(wide):
    """Walk the wide tree from the root, checking its invariants; returns how many leaf slots hold
    each primitive position, and the number of levels."""
    w_lo, w_hi, w_child, w_count = wide
    covered = np.zeros(int(w_child[w_count > 0].max() + MAX_LEAF + 1), np.int64)
    seen = np.zeros(len(w_child), np.int64)
    levels = 0
    stack = [(0, 1)]
    while stack:
        i, level = stack.pop()
        levels = max(levels, level)
        seen[i] += 1
        for c in range(BVH_WIDTH):
            if w_count[i, c] < 0:  # an empty slot: a box no ray can enter
                assert np.all(w_lo[i, :, c] == np.inf) and np.all(w_hi[i, :, c] == np.inf)
                continue
            assert np.all(w_lo[i, :, c] <= w_hi[i, :, c])
            if w_count[i, c] > 0:
                assert w_count[i, c] <= MAX_LEAF
                covered[w_child[i, c]:w_child[i, c] + w_count[i, c]] += 1
            else:
                child = w_child[i, c]
                assert i < child < len(w_child)
                used = w_count[child] >= 0
                assert np.all(w_lo[i, :, c, None] <= w_lo[child][:, used])
                assert np.all(w_hi[child][:, used] <= w_hi[i, :, c, None])
                stack.append((child, level + 1))
    np.testing.assert_array_equal(seen, 1)  # every node reached once
    return covered, levels


def test_wide_bvh_structure(rng):
    # The wide tree holds every primitive in exactly one leaf, every box contains what is below
    # it, no node is left half empty while a child could still be opened, and the depth it
    # reports (which sizes the traversal stack) is the depth of the tree.
    kind, geo = random_scene(rng)
    nodes, order = build_binary(kind, geo)
    w_lo, w_hi, w_child, w_count, depth = widen_bvh(*nodes)
    covered, levels = wide_leaves((w_lo, w_hi, w_child, w_count))
    np.testing.assert_array_equal(covered[:len(kind)], 1)
    assert covered[len(kind):].sum() == 0
    assert depth == levels
    assert stack_size(depth) <= STACK_SIZE
    # Leaf boxes are their primitives' bounds, exactly
    lo, hi = prim_bounds(kind[order], geo[order])
    for i, c in zip(*np.nonzero(w_count > 0), strict=True):
        idx = slice(w_child[i, c], w_child[i, c] + w_count[i, c])
        np.testing.assert_array_equal(w_lo[i, :, c], lo[idx].min(axis=0))
        np.testing.assert_array_equal(w_hi[i, :, c], hi[idx].max(axis=0))
    # A wide node is full unless all its children are leaves
    for i in range(len(w_child)):
        if np.any(w_count[i] < 0):
            assert np.all(w_count[i] != 0)
    # Fewer nodes than the binary tree's interior nodes
    assert len(w_child) <= max(1, int(np.sum(nodes[3] == 0)))


def test_bvh_with_coincident_primitives(rng):
    # 60 copies of one triangle and 60 of one sphere: no plane separates their centroids, so the
    # build must split by count; the closest hit is still found and every copy lies in one leaf.
    tri = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0])
    sph = np.array([3.0, 0.0, 0.0, 0.5, 0, 0, 0, 0, 0])
    kind = np.array([TRIANGLE] * 60 + [SPHERE] * 60, np.int8)
    geo = np.array([tri] * 60 + [sph] * 60)
    bvh, order, prim_kind, prim_geo = build(kind, geo)
    covered, _ = wide_leaves(bvh[:4])
    np.testing.assert_array_equal(covered[:len(kind)], 1)
    stack = traversal_stack(STACK_SIZE)
    t, prim, _, _ = intersect_closest(*bvh, prim_kind, prim_geo, (0.2, 0.2, 5.0), (0.0, 0.0, -1.0),
                                      np.inf, stack)
    assert t == 5.0 and prim_kind[prim] == TRIANGLE
    t, prim, _, _ = intersect_closest(*bvh, prim_kind, prim_geo, (3.0, 0.0, 5.0), (0.0, 0.0, -1.0),
                                      np.inf, stack)
    assert t == 4.5 and prim_kind[prim] == SPHERE
    assert occluded(*bvh, prim_kind, prim_geo, (3.0, 0.0, 5.0), (0.0, 0.0, -1.0), 4.6, stack)
    assert not occluded(*bvh, prim_kind, prim_geo, (3.0, 0.0, 5.0), (0.0, 0.0, -1.0), 4.4, stack)


@pytest.mark.parametrize("n", [1, 2, 9])
def test_bvh_small(rng, n):
    # A single primitive is a single leaf; tiny scenes still agree with brute force.
    kind, geo = random_scene(rng, n_tri=n, n_sph=0, n_quad=0)
    bvh, order, prim_kind, prim_geo = build(kind, geo)
    if n == 1:  # one node whose one slot is a leaf
        assert len(bvh[3]) == 1 and bvh[3][0, 0] == 1 and np.all(bvh[3][0, 1:] == -1)
    origins = np.repeat(geo[:, 0:3] + 5.0, 20, axis=0)
    targets = np.repeat(geo[:, 0:3] + 0.25 * geo[:, 3:6] + 0.25 * geo[:, 6:9], 20, axis=0)
    dirs = targets - origins + rng.normal(scale=0.05, size=origins.shape)
    res, occ = _compare_many(bvh, prim_kind, prim_geo, origins, dirs, np.ones(len(origins)))
    np.testing.assert_array_equal(res[:, 0], res[:, 1])
    np.testing.assert_array_equal(occ[:, 0], occ[:, 1])


def test_bvh_of_no_primitives():
    # build_bvh over zero primitives must give an empty tree that every query misses. Run in a
    # child process: the build writes past its node arrays when it goes wrong, which can abort
    # the interpreter or loop until it does, rather than raise. 30 s is ample for the child to
    # start and load the kernels this module has already compiled into the shared cache.
    code = (
        "import numpy as np\n"
        "from renderer.geometry.bvh import build_bvh, intersect_closest, occluded, STACK_SIZE\n"
        "from renderer.geometry.bvh import traversal_stack, widen_bvh\n"
        "b = build_bvh(np.empty((0, 3)), np.empty((0, 3)))\n"
        "assert b[3].sum() == 0 and len(b[4]) == 0, b\n"
        "w = widen_bvh(*b[:4])\n"
        "assert len(w[2]) == 0 and w[4] == 0, w\n"
        "b = (*w[:4], np.zeros((10, 0)))\n"
        "s = traversal_stack(STACK_SIZE)\n"
        "k, g = np.empty(0, np.int8), np.empty((0, 9))\n"
        "o, d = (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)\n"
        "assert intersect_closest(*b, k, g, o, d, np.inf, s)[1] == -1\n"
        "assert not occluded(*b, k, g, o, d, np.inf, s)\n"
        "print('ok')\n"
    )
    try:
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              timeout=30)
    except subprocess.TimeoutExpired:
        pytest.fail("build_bvh over 0 primitives did not return within 30 s")
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", (
        f"build_bvh over 0 primitives: exit code {proc.returncode}\n{proc.stderr[-2000:]}")


def test_ray_through_shared_edge_hits(rng):
    # Two triangles sharing an edge (a quad split along its diagonal): rays aimed exactly at the
    # shared edge hit one of them, never slip through the crack. Edge points are chosen on the
    # diagonal in exact binary fractions so that the test is about the hit rule, not rounding.
    v0, v1, v2, v3 = (np.array(p, float) for p in ([0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]))
    geo = np.array([[*v0, *(v1 - v0), *(v2 - v0)], [*v0, *(v2 - v0), *(v3 - v0)]])
    kind = np.array([TRIANGLE, TRIANGLE], np.int8)
    bvh, order, prim_kind, prim_geo = build(kind, geo)
    stack = traversal_stack(STACK_SIZE)
    for s in np.arange(1, 16) / 16.0:
        t, prim, _, _ = intersect_closest(*bvh, prim_kind, prim_geo, (s, s, 2.0),
                                          (0.0, 0.0, -1.0), np.inf, stack)
        assert prim >= 0 and t == 2.0, s
    assert math.isinf(intersect_closest(*bvh, prim_kind, prim_geo, (1.5, 0.5, 2.0),
                                        (0.0, 0.0, -1.0), np.inf, stack)[0])


# --- flat scenes ----------------------------------------------------------------------------------


def aimed_rays(rng, geo, kind, per_prim):
    """Rays from 5 away aimed at points around each primitive (most hit, some miss), and some
    axis-aligned ones."""
    geo = np.repeat(geo, per_prim, axis=0)
    sph = np.repeat(kind == SPHERE, per_prim)
    a, b = rng.uniform(-0.1, 1.1, (2, len(geo), 1))
    targets = np.where(sph[:, None],
                       geo[:, 0:3] + 1.2 * geo[:, 3:4] * rng.uniform(-1, 1, (len(geo), 3)),
                       geo[:, 0:3] + a * geo[:, 3:6] + b * geo[:, 6:9])
    origins = targets + 5.0 * unit_rows(rng.normal(size=targets.shape))
    dirs = targets - origins
    k = len(dirs) // 10
    dirs[:k] = np.eye(3)[rng.integers(0, 3, k)] * rng.choice([-1.0, 1.0], (k, 1))
    return origins, dirs


@pytest.mark.parametrize("n_tri,n_sph,n_quad", [(1, 0, 0), (0, 1, 0), (0, 0, 2), (5, 2, 2),
                                                (8, 4, 12), (0, 0, FLAT_MAX)])
def test_flat_matches_brute_force(rng, n_tri, n_sph, n_quad):
    # The flat search gives the closest primitive, t and (u, v) of a test of every primitive in
    # order, bit for bit, and occluded() agrees with it, for any mix of kinds up to FLAT_MAX
    # (columns of padding included: 1, 2, 9, 24 primitives).
    kind, geo = random_scene(rng, n_tri=n_tri, n_sph=n_sph, n_quad=n_quad)
    geo[:, 0:3] *= 0.2  # closer together, so that primitives hide one another
    flat, order, prim_kind, prim_geo = build_flat(kind, geo)
    assert np.all(np.diff((prim_kind != SPHERE).astype(int)) >= 0)  # spheres first
    origins, dirs = aimed_rays(rng, prim_geo, prim_kind, 200)
    factors = rng.uniform(0.5, 1.5, len(origins))
    res, occ = _compare_many(flat, prim_kind, prim_geo, origins, dirs, factors)
    hit = res[:, 1, 1] >= 0
    assert 0.2 < hit.mean() < 0.98
    np.testing.assert_array_equal(res[:, 0], res[:, 1])  # primitive, t, (u, v), exactly
    np.testing.assert_array_equal(occ[:, 0], occ[:, 1])
    assert 0 < occ[:, 0].sum() < len(origins)
    if n_tri + n_sph + n_quad >= 9:  # most primitives (some are hidden) are the closest of some
        assert len(np.unique(res[hit, 1, 1])) >= 0.8 * len(kind)


@pytest.mark.parametrize("pad", [4, 8])
@pytest.mark.parametrize("n", [1, 15, 16, 17, 20, 21, FLAT_MAX - 1, FLAT_MAX])
def test_flat_store_is_padded_with_empty_columns(rng, n, pad):
    # The vector loop takes whole vectors of `pad` columns (AVX2: 4, from 16 columns on; AVX-512:
    # 16, then 8); the store is padded to them with all-zero columns, which no ray hits, and
    # with no more columns than that needs.
    kind, geo = random_scene(rng, n_tri=n // 2, n_sph=1, n_quad=n - n // 2 - 1)
    kind, geo = kind[flat_order(kind)], geo[flat_order(kind)]
    flat = flat_geometry(kind, geo, pad)
    assert flat.shape[1] == max(FLAT_MIN_COLUMNS, -(-n // pad) * pad)
    assert flat.shape[1] % pad == 0 and flat.shape[1] - max(n, FLAT_MIN_COLUMNS) < pad
    assert flat.shape[1] <= FLAT_MAX
    assert np.all(flat[:, n:] == 0.0) and np.all(flat[:, :n][:, kind == SPHERE] == 0.0)
    np.testing.assert_array_equal(flat[:9, :n][:, kind != SPHERE], geo[kind != SPHERE].T)
    np.testing.assert_array_equal(flat[9, :n], kind == TRIANGLE)
    assert flat_geometry(kind[:0], geo[:0]).shape == (FLAT_ROWS, 0)


def test_vector_pad_follows_the_cpu_that_numba_compiles_for():
    zen3 = "+avx,+avx2,+fma,+sse4.2,-avx512f,-avx512vl"
    assert vector_pad(zen3) == 4
    assert vector_pad("+avx,+avx2,+avx512f,+avx512vl,+fma") == 8  # Zen 4, AVX-512 Xeons
    assert vector_pad("+sse2,+sse4.2,-avx,-avx2") == 8  # SSE: 2 doubles, a multiple of 8
    assert vector_pad("+neon,+fp-armv8") == 8
    assert vector_pad("") == 8
    # The store this process builds follows the CPU numba compiles for (NUMBA_CPU_FEATURES)
    script = "from renderer.geometry.flat import FLAT_PAD; print(FLAT_PAD)"
    for features, pad in ((zen3, 4), ("+avx2,+avx512f", 8)):
        env = {**os.environ, "NUMBA_CPU_FEATURES": features}
        out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True,
                             text=True, check=True).stdout
        assert int(out) == pad
    assert FLAT_PAD in (4, 8)


def test_the_padding_leaves_every_hit_the_same():
    # The same Cornell box (18 quads) rendered from a store of 20 columns and one of 24 (the
    # AVX2 and the AVX-512 padding): bit-identical sample buffers
    scene = json.loads((Path(__file__).parents[3] / "examples" / "cornell_box.json").read_text())
    scene["film"] = {"width": 32, "height": 24}
    cs = compile_scene(load_scene(scene))
    buffers = []
    for pad in (4, 8):
        flat = flat_geometry(cs.arrays.prim_kind, cs.arrays.prim_geo, pad)
        assert flat.shape[1] == {4: 20, 8: 24}[pad]
        padded = dataclasses.replace(cs, arrays=cs.arrays._replace(flat=flat))
        buffers.append(render_tile(padded, 0, 0, 32, 24, 0, 4, kernel="scalar"))  # (its flat)
    for name in ("sum", "sum_sq", "count"):
        np.testing.assert_array_equal(getattr(buffers[0], name), getattr(buffers[1], name))
    assert buffers[0].sum.sum() > 0


def test_flat_coplanar_tie_goes_to_the_first():
    # Two quads in one plane overlapping, and a sphere touching it: on an exact tie in t the
    # first primitive in order wins, as in the brute-force loop (and a sphere before a quad).
    quad = [-1.0, -1.0, 0.0, 2.0, 0.0, 0.0, 0.0, 2.0, 0.0]
    kind = np.array([QUAD, QUAD, SPHERE], np.int8)
    geo = np.array([quad, quad, [0.0, 0.0, -1.0, 1.0, 0, 0, 0, 0, 0]])
    flat, order, prim_kind, prim_geo = build_flat(kind, geo)
    assert list(order) == [2, 0, 1]
    stack = traversal_stack(STACK_SIZE)
    t, prim, _, _ = intersect_closest(*flat, prim_kind, prim_geo, (0.5, 0.5, 2.0),
                                      (0.0, 0.0, -1.0), np.inf, stack)
    assert t == 2.0 and prim == 1  # the first quad, not its copy
    t, prim, u, v = intersect_closest(*flat, prim_kind, prim_geo, (0.0, 0.0, 2.0),
                                      (0.0, 0.0, -1.0), np.inf, stack)
    assert t == 2.0 and prim == 0 and (u, v) == (0.0, 0.0)  # the sphere's top ties the quads
    assert occluded(*flat, prim_kind, prim_geo, (0.5, 0.5, 2.0), (0.0, 0.0, -1.0), 2.5, stack)
    assert not occluded(*flat, prim_kind, prim_geo, (0.5, 0.5, 2.0), (0.0, 0.0, -1.0), 1.5,
                        stack)
