"""Bounding volume hierarchy: binned surface-area-heuristic build and stack traversal.

The layout is pbrt's ``LinearBVHNode``: nodes in depth-first order, so an interior node's first
child is the next node and only the second child's index is stored. ``node_count[i] > 0`` marks a
leaf holding primitives ``node_offset[i] … node_offset[i] + node_count[i] − 1`` (in BVH order);
otherwise ``node_offset[i]`` is the second child.

The traversal walks a wide tree collapsed from it (``widen_bvh``: ``BVH_WIDTH`` children a node,
as Embree's BVH8): fewer, fatter nodes, their children visited nearest first by entry distance,
cost fewer stack operations and mispredicted branches than the binary tree's one box at a time
(5-25 % faster renders, docs/performance.md). The hits are the same, the closest one exactly that
of a test of every primitive, except where two primitives are hit at exactly the same distance
(coplanar faces): the one tested first wins, and the order differs from the binary tree's.

The build bins centroids into 16 buckets per axis (Wald, "On fast construction of SAH-based
bounding volume hierarchies", 2007), which is O(n log n) and builds a million triangles in about a
second once compiled.
"""

from __future__ import annotations

import numpy as np

from renderer.geometry.flat import FLAT_MAX, flat_closest, flat_occluded
from renderer.geometry.shapes import INF, intersect_prim
from renderer.jit import alloc_kernel, inline_kernel, kernel

N_BUCKETS = 16
MAX_LEAF = 8
STACK_SIZE = 128  # a traversal stack for any tree the tests build (scenes size theirs)
# Children per node of the tree the traversal walks (widen_bvh)
BVH_WIDTH = 8


@kernel
def _area(lo0, lo1, lo2, hi0, hi1, hi2):
    dx, dy, dz = hi0 - lo0, hi1 - lo1, hi2 - lo2
    return 2.0 * (dx * dy + dy * dz + dz * dx)


@kernel
def _grow(b_lo, b_hi, b, l0, l1, l2, h0, h1, h2):
    """The box (l0..2, h0..2) grown to hold bucket b's bounds."""
    return (min(l0, b_lo[b, 0]), min(l1, b_lo[b, 1]), min(l2, b_lo[b, 2]),
            max(h0, b_hi[b, 0]), max(h1, b_hi[b, 1]), max(h2, b_hi[b, 2]))


@kernel
def _centroid(lo, hi, i, axis):
    """A primitive's box centre, computed where needed rather than stored: (n, 3) floats fewer."""
    return 0.5 * (lo[i, axis] + hi[i, axis])


@alloc_kernel
def build_bvh(lo, hi):
    """Build over primitive bounds ``lo``/``hi`` (n, 3). Returns the node arrays and the order.

    Returns (node_lo, node_hi, node_offset, node_count, order): ``order[k]`` is the
    original index of the primitive stored at BVH position k.
    """
    n = lo.shape[0]
    order = np.arange(n).astype(np.int64)
    max_nodes = max(1, 2 * n - 1)
    node_lo = np.empty((max_nodes, 3))
    node_hi = np.empty((max_nodes, 3))
    node_offset = np.zeros(max_nodes, np.int64)
    node_count = np.zeros(max_nodes, np.int64)

    # Work items: (start, end, parent); parent < 0 for the root, and a parent index is recorded
    # so the second child can write its own index into the parent once it is allocated.
    stack_start = np.empty(256, np.int64)
    stack_end = np.empty(256, np.int64)
    stack_parent = np.empty(256, np.int64)
    stack_start[0] = 0
    stack_end[0] = n
    stack_parent[0] = -1
    sp = 1 if n > 0 else 0  # no primitives, no nodes: the traversal treats that as a miss
    n_nodes = 0
    b_count = np.zeros(N_BUCKETS, np.int64)
    b_lo = np.empty((N_BUCKETS, 3))
    b_hi = np.empty((N_BUCKETS, 3))
    cost = np.empty(N_BUCKETS - 1)

    while sp > 0:
        sp -= 1
        start = stack_start[sp]
        end = stack_end[sp]
        parent = stack_parent[sp]
        node = n_nodes
        n_nodes += 1
        if parent >= 0:
            node_offset[parent] = node  # only second children are pushed with a parent

        # Bounds of the primitives and of their centroids
        blo0 = blo1 = blo2 = INF
        bhi0 = bhi1 = bhi2 = -INF
        clo0 = clo1 = clo2 = INF
        chi0 = chi1 = chi2 = -INF
        for k in range(start, end):
            i = order[k]
            blo0 = min(blo0, lo[i, 0])
            blo1 = min(blo1, lo[i, 1])
            blo2 = min(blo2, lo[i, 2])
            bhi0 = max(bhi0, hi[i, 0])
            bhi1 = max(bhi1, hi[i, 1])
            bhi2 = max(bhi2, hi[i, 2])
            c0 = _centroid(lo, hi, i, 0)
            c1 = _centroid(lo, hi, i, 1)
            c2 = _centroid(lo, hi, i, 2)
            clo0 = min(clo0, c0)
            clo1 = min(clo1, c1)
            clo2 = min(clo2, c2)
            chi0 = max(chi0, c0)
            chi1 = max(chi1, c1)
            chi2 = max(chi2, c2)
        node_lo[node, 0] = blo0
        node_lo[node, 1] = blo1
        node_lo[node, 2] = blo2
        node_hi[node, 0] = bhi0
        node_hi[node, 1] = bhi1
        node_hi[node, 2] = bhi2
        count = end - start

        # Pick the split: the axis of largest centroid extent, SAH over buckets on every axis
        best_cost = INF
        best_axis = -1
        best_bucket = -1
        if count > 1:
            for axis in range(3):
                c_lo = clo0 if axis == 0 else (clo1 if axis == 1 else clo2)
                c_hi = chi0 if axis == 0 else (chi1 if axis == 1 else chi2)
                extent = c_hi - c_lo
                if not extent > 0.0:
                    continue
                b_count[:] = 0
                b_lo[:, :] = INF
                b_hi[:, :] = -INF
                for k in range(start, end):
                    i = order[k]
                    b = int(N_BUCKETS * (_centroid(lo, hi, i, axis) - c_lo) / extent)
                    if b >= N_BUCKETS:
                        b = N_BUCKETS - 1
                    b_count[b] += 1
                    for j in range(3):
                        b_lo[b, j] = min(b_lo[b, j], lo[i, j])
                        b_hi[b, j] = max(b_hi[b, j], hi[i, j])
                # Sweep from below and from above to get the SAH cost of every split plane
                c_below = 0
                l0 = l1 = l2 = INF
                h0 = h1 = h2 = -INF
                for b in range(N_BUCKETS - 1):
                    c_below += b_count[b]
                    l0, l1, l2, h0, h1, h2 = _grow(b_lo, b_hi, b, l0, l1, l2, h0, h1, h2)
                    cost[b] = c_below * _area(l0, l1, l2, h0, h1, h2) if c_below > 0 else 0.0
                c_above = 0
                l0 = l1 = l2 = INF
                h0 = h1 = h2 = -INF
                for b in range(N_BUCKETS - 1, 0, -1):
                    c_above += b_count[b]
                    l0, l1, l2, h0, h1, h2 = _grow(b_lo, b_hi, b, l0, l1, l2, h0, h1, h2)
                    if c_above > 0:
                        cost[b - 1] += c_above * _area(l0, l1, l2, h0, h1, h2)
                for b in range(N_BUCKETS - 1):
                    if cost[b] < best_cost:
                        best_cost = cost[b]
                        best_axis = axis
                        best_bucket = b

        # pbrt-v4's rule: traversal costs 1/2 of an intersection; make a leaf when that is cheaper
        # and the leaf is small, or when no plane separates the centroids at all.
        area = _area(blo0, blo1, blo2, bhi0, bhi1, bhi2)
        split_cost = 0.5 + best_cost / area if area > 0.0 else INF
        make_leaf = count == 1 or (count <= MAX_LEAF and split_cost >= count)
        mid = start
        if not make_leaf:
            if best_axis < 0:
                # All centroids coincide: split by count so leaves stay small.
                mid = (start + end) // 2
            else:
                c_lo = clo0 if best_axis == 0 else (clo1 if best_axis == 1 else clo2)
                c_hi = chi0 if best_axis == 0 else (chi1 if best_axis == 1 else chi2)
                extent = c_hi - c_lo
                # Partition in place: bucket ≤ best_bucket goes left
                i0 = start
                i1 = end - 1
                while i0 <= i1:
                    p = order[i0]
                    b = int(N_BUCKETS * (_centroid(lo, hi, p, best_axis) - c_lo) / extent)
                    if b >= N_BUCKETS:
                        b = N_BUCKETS - 1
                    if b <= best_bucket:
                        i0 += 1
                    else:
                        order[i0] = order[i1]
                        order[i1] = p
                        i1 -= 1
                mid = i0
                if mid == start or mid == end:
                    mid = (start + end) // 2
        if make_leaf:
            node_offset[node] = start
            node_count[node] = count
        else:
            node_count[node] = 0
            if sp + 2 > stack_start.shape[0]:
                grow = stack_start.shape[0] * 2
                s2 = np.empty(grow, np.int64)
                e2 = np.empty(grow, np.int64)
                p2 = np.empty(grow, np.int64)
                s2[:sp] = stack_start[:sp]
                e2[:sp] = stack_end[:sp]
                p2[:sp] = stack_parent[:sp]
                stack_start, stack_end, stack_parent = s2, e2, p2
            # Second child first, so the first child is popped next and lands at node + 1
            stack_start[sp] = mid
            stack_end[sp] = end
            stack_parent[sp] = node
            sp += 1
            stack_start[sp] = start
            stack_end[sp] = mid
            stack_parent[sp] = -1
            sp += 1

    return (
        node_lo[:n_nodes].copy(),
        node_hi[:n_nodes].copy(),
        node_offset[:n_nodes].copy(),
        node_count[:n_nodes].copy(),
        order,
    )


@kernel
def _open_children(node_lo, node_hi, node_offset, node_count, b, kids):
    """The children of binary node b for one wide node, in ``kids``: its two children, then the
    largest interior one (by surface area) replaced by its own two, until there are
    ``BVH_WIDTH`` or only leaves. Returns how many."""
    if node_count[b] > 0:  # a tree that is a single leaf
        kids[0] = b
        return 1
    kids[0] = b + 1
    kids[1] = node_offset[b]
    k = 2
    while k < BVH_WIDTH:
        best = -1
        best_area = -1.0
        for j in range(k):
            c = kids[j]
            if node_count[c] == 0:
                a = _area(node_lo[c, 0], node_lo[c, 1], node_lo[c, 2],
                          node_hi[c, 0], node_hi[c, 1], node_hi[c, 2])
                if a > best_area:
                    best_area = a
                    best = j
        if best < 0:
            break
        c = kids[best]
        kids[best] = c + 1
        kids[k] = node_offset[c]
        k += 1
    return k


@alloc_kernel
def widen_bvh(node_lo, node_hi, node_offset, node_count):
    """Collapse the binary tree into a ``BVH_WIDTH``-wide one (Wald et al., "Getting rid of
    packets", 2008; Embree's BVH4/BVH8): each wide node takes a binary node's children and keeps
    opening its largest interior child until it has ``BVH_WIDTH`` of them.

    Returns (lo, hi, child, count, depth): ``lo``/``hi`` (n, 3, W) are the children's boxes, axis
    by axis (float64: float32 boxes rounded outwards were 3-15 % slower, the conversions costing
    more than the cache lines saved); ``count[i, c] > 0`` marks a leaf child holding primitives
    ``child[i, c]`` … ``child[i, c] + count[i, c] − 1``, ``count[i, c] == 0`` an interior child
    (wide node ``child[i, c]``) and −1 an empty slot, whose box (+inf, +inf) no ray enters.
    ``depth`` is the number of wide levels. Node 0 is the root; a scene without primitives has no
    nodes. ``child`` and ``count`` are int32 (compile_scene refuses 2³¹ primitives).
    """
    n = node_offset.shape[0]
    kids = np.empty(BVH_WIDTH, np.int64)
    # Work items are binary interior nodes, each queued once: their number bounds the queue.
    n_interior = 0
    for i in range(n):
        if node_count[i] == 0:
            n_interior += 1
    todo = np.empty(n_interior + 1, np.int64)
    # A first pass counts the wide nodes, so the arrays are allocated once at their size (for a
    # million triangles an upper bound would be ~500 MiB of boxes)
    n_wide = 0
    top = 1 if n > 0 else 0
    todo[0] = 0
    while top > 0:
        top -= 1
        n_wide += 1
        k = _open_children(node_lo, node_hi, node_offset, node_count, todo[top], kids)
        for j in range(k):
            if node_count[kids[j]] == 0:
                todo[top] = kids[j]
                top += 1
    w_lo = np.full((n_wide, 3, BVH_WIDTH), INF)
    w_hi = np.full((n_wide, 3, BVH_WIDTH), INF)
    w_child = np.zeros((n_wide, BVH_WIDTH), np.int32)
    w_count = np.full((n_wide, BVH_WIDTH), -1, np.int32)
    todo_wide = np.empty(n_interior + 1, np.int64)
    todo_depth = np.empty(n_interior + 1, np.int64)
    todo[0] = 0
    todo_wide[0] = 0
    todo_depth[0] = 1
    top = 1 if n > 0 else 0
    made = 1
    depth = 0
    while top > 0:
        top -= 1
        w = todo_wide[top]
        level = todo_depth[top]
        depth = max(depth, level)
        k = _open_children(node_lo, node_hi, node_offset, node_count, todo[top], kids)
        for j in range(k):
            c = kids[j]
            for a in range(3):
                w_lo[w, a, j] = node_lo[c, a]
                w_hi[w, a, j] = node_hi[c, a]
            if node_count[c] > 0:
                w_child[w, j] = node_offset[c]
                w_count[w, j] = node_count[c]
            else:
                w_child[w, j] = made
                w_count[w, j] = 0
                todo[top] = c
                todo_wide[top] = made
                todo_depth[top] = level + 1
                top += 1
                made += 1
    return w_lo, w_hi, w_child, w_count, depth


def stack_size(depth):
    """Entries the traversal stack needs for a wide tree of ``depth`` levels: a visit pops one
    entry and pushes at most ``BVH_WIDTH``."""
    return depth * (BVH_WIDTH - 1) + 2


@alloc_kernel
def traversal_stack(size):
    """A traversal stack: (entries, entry distances, scratch). An entry is a slot ``node·W + c``
    of the wide tree's ``child``/``count`` arrays; the scratch holds a flat scene's distances
    (renderer.geometry.flat)."""
    return np.empty(size, np.int64), np.empty(size), np.empty((3, FLAT_MAX))


@kernel
def _slab(node_lo, node_hi, node, c, o, inv_d, t_max):
    """Entry distance of the ray into child c's box, or inf when it misses within (0, t_max)."""
    t0 = 0.0
    t1 = t_max
    for a in range(3):
        ta = (node_lo[node, a, c] - o[a]) * inv_d[a]
        tb = (node_hi[node, a, c] - o[a]) * inv_d[a]
        if ta > tb:
            ta, tb = tb, ta
        # Widen the far side by 2γ(3) so a ray grazing a box face is not lost to rounding
        # (pbrt-v4, Bounds3::IntersectP).
        tb *= 1.0 + 6.7e-16
        if ta > t0:
            t0 = ta
        if tb < t1:
            t1 = tb
    # One test at the end rather than one an axis: t0 only grows and t1 only shrinks, so the
    # answer is the same, and the code has no branch the CPU could mispredict
    return t0 if t0 <= t1 else INF


@inline_kernel
def intersect_closest(bvh_lo, bvh_hi, bvh_child, bvh_count, flat, prim_kind, prim_geo, o, d,
                      t_max, stack):
    """Closest hit along the ray within (0, t_max): (t, prim, u, v), prim = -1 on a miss.

    A flat scene (``flat`` has a column a primitive) is searched without the tree. Otherwise a
    node's children are tested one after the other and the ones the ray enters are pushed sorted
    by entry distance, nearest on top; an entry popped after a hit nearer than its box is dropped
    (Embree's ordered traversal).
    """
    slots, dist, scratch = stack
    if flat.shape[1] > 0:
        return flat_closest(flat, prim_kind, prim_geo, o, d, t_max, scratch)
    inv_d = (1.0 / d[0], 1.0 / d[1], 1.0 / d[2])
    best_t = t_max
    best_prim = -1
    best_u = 0.0
    best_v = 0.0
    if bvh_child.shape[0] == 0:
        return INF, -1, 0.0, 0.0
    sp = 0
    node = 0
    while node >= 0:
        base = sp
        for c in range(BVH_WIDTH):
            t = _slab(bvh_lo, bvh_hi, node, c, o, inv_d, best_t)
            if t < INF:
                # Insertion into the entries pushed for this node, farthest at the bottom
                j = sp
                while j > base and dist[j - 1] < t:
                    dist[j] = dist[j - 1]
                    slots[j] = slots[j - 1]
                    j -= 1
                dist[j] = t
                slots[j] = node * BVH_WIDTH + c
                sp += 1
        node = -1
        while sp > 0:
            sp -= 1
            if dist[sp] > best_t:
                continue
            node_c = slots[sp] // BVH_WIDTH
            c = slots[sp] - node_c * BVH_WIDTH
            count = bvh_count[node_c, c]
            if count == 0:
                node = bvh_child[node_c, c]
                break
            first = bvh_child[node_c, c]
            for k in range(first, first + count):
                t, u, v = intersect_prim(prim_kind[k], o, d, prim_geo[k])
                if t < best_t:
                    best_t = t
                    best_prim = k
                    best_u = u
                    best_v = v
    if best_prim < 0:
        return INF, -1, 0.0, 0.0
    return best_t, best_prim, best_u, best_v


@inline_kernel
def occluded(bvh_lo, bvh_hi, bvh_child, bvh_count, flat, prim_kind, prim_geo, o, d, t_max,
             stack):
    """True when anything lies on the ray within (0, t_max): the any-hit query of shadow rays.
    Leaves are tested as soon as their box is entered; interior children are pushed unsorted."""
    slots, _, scratch = stack
    if flat.shape[1] > 0:
        return flat_occluded(flat, prim_kind, prim_geo, o, d, t_max, scratch)
    if bvh_child.shape[0] == 0:
        return False
    inv_d = (1.0 / d[0], 1.0 / d[1], 1.0 / d[2])
    sp = 0
    node = 0
    while True:
        for c in range(BVH_WIDTH):
            if _slab(bvh_lo, bvh_hi, node, c, o, inv_d, t_max) < INF:
                count = bvh_count[node, c]
                if count == 0:
                    slots[sp] = bvh_child[node, c]
                    sp += 1
                else:
                    first = bvh_child[node, c]
                    for k in range(first, first + count):
                        t, _, _ = intersect_prim(prim_kind[k], o, d, prim_geo[k])
                        if t < t_max:
                            return True
        if sp == 0:
            return False
        sp -= 1
        node = slots[sp]
