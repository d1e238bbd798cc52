"""The wavefront kernel against the scalar kernel, the references and closed forms; its stages
against plain NumPy."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from renderer.film.buffer import SampleBuffer
from renderer.geometry.bvh import intersect_closest, traversal_stack
from renderer.render import render, render_tile
from renderer.rng import sample_key, uniform
from renderer.scene import load_scene
from renderer.scene.compile import compile_scene
from renderer.wavefront import gpu_missing
from renderer.wavefront.cpu import batching, render_tile_wavefront, unsupported
from renderer.wavefront.stages import accumulate, compact, generate, intersect
from renderer.wavefront.state import path_state

ROOT = Path(__file__).resolve().parents[3]
EXAMPLES = ROOT / "examples"
DATA = ROOT / "tests" / "data"


def example(name: str, width=24, height=18, **render_settings) -> dict:
    data = json.loads((EXAMPLES / f"{name}.json").read_text())
    data["film"] = {"width": width, "height": height}
    data["render"].update(render_settings)
    return data


def both(cs, sample_start=0, sample_count=8, active=None, **kw):
    active = np.ones((cs.height, cs.width), np.uint8) if active is None else active
    scalar = render_tile(cs, 0, 0, cs.width, cs.height, sample_start, sample_count, active,
                         kernel="scalar")
    wave = render_tile_wavefront(cs, 0, 0, cs.width, cs.height, sample_start, sample_count,
                                 active, **kw)
    return scalar, wave


def assert_same_buffer(a: SampleBuffer, b: SampleBuffer, rtol=1e-12):
    np.testing.assert_array_equal(a.count, b.count)
    np.testing.assert_array_equal(a.dropped, b.dropped)
    np.testing.assert_allclose(a.sum, b.sum, rtol=rtol, atol=1e-300)
    np.testing.assert_allclose(a.sum_sq, b.sum_sq, rtol=rtol, atol=1e-300)


SURFACE_SCENE = {
    # Every surface material the kernel covers, lit by an area light, a point light and the
    # background, in a box searched with the tree (more than FLAT_MAX primitives)
    "camera": {"position": [0, 0, 3.9], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 39.0},
    "film": {"width": 24, "height": 18},
    "render": {"spp": 8, "max_depth": -1, "seed": 3},
    "background": [0.1, 0.12, 0.15],
    "materials": {
        "white": {"type": "diffuse", "albedo": [0.73, 0.73, 0.73]},
        "mirror": {"type": "mirror", "reflectance": [0.9, 0.9, 0.9]},
        "gold": {"type": "conductor", "preset": "Au"},
        "rough_cu": {"type": "conductor", "preset": "Cu", "roughness": 0.2},
        "glass": {"type": "dielectric", "ior": 1.5, "absorption": [0.2, 0.5, 0.9]},
        "frosted": {"type": "dielectric", "ior": 1.4, "roughness": 0.25},
        "plastic": {"type": "phong", "diffuse": [0.1, 0.2, 0.5], "specular": [0.3, 0.3, 0.3],
                    "exponent": 40},
    },
    "objects": (
        [{"type": "quad", "origin": [-1, -1, 1], "edge1": [2, 0, 0], "edge2": [0, 0, -2],
          "material": "white"},
         {"type": "quad", "origin": [-1, -1, -1], "edge1": [2, 0, 0], "edge2": [0, 2, 0],
          "material": "white"},
         {"type": "quad", "origin": [-0.25, 0.99, -0.25], "edge1": [0.5, 0, 0],
          "edge2": [0, 0, 0.5], "material": "white", "emission": [8, 8, 8]}]
        + [{"type": "sphere", "center": [-0.8 + 0.4 * (k % 5), -0.75 + 0.5 * (k // 5), -0.3],
            "radius": 0.17, "material": m}
           for k, m in enumerate(["mirror", "gold", "rough_cu", "glass", "frosted", "plastic",
                                  "white"] * 4)]
    ),
    "lights": [{"type": "point", "position": [0.5, 0.5, 1.5], "intensity": [2, 2, 2]}],
}


@pytest.mark.parametrize("name", ["cornell_box", "glass_sphere"])
def test_the_examples_agree_with_the_scalar_kernel(name):
    """The wavefront kernel traces the scalar kernel's paths (same random dimensions, same
    arithmetic), so the sample buffers agree to rounding: the only freedom is float64 addition
    order, hence 1e-12 relative. A mistake in any stage (a wrong MIS weight, a lost shadow ray, a
    dimension off by one) changes pixels by far more."""
    cs = compile_scene(load_scene(example(name)))
    assert unsupported(cs) is None
    assert_same_buffer(*both(cs, sample_start=3, sample_count=6))


def test_every_surface_material_and_light_agrees_with_the_scalar_kernel():
    cs = compile_scene(load_scene(SURFACE_SCENE))
    assert unsupported(cs) is None
    assert cs.arrays.flat.shape[1] == 0  # searched with the BVH
    assert_same_buffer(*both(cs))


@pytest.mark.parametrize("scene", ["env_rough_glass_sphere", "env_diffuse_sphere"])
def test_environment_images_agree_with_the_scalar_kernel(scene):
    data = json.loads((DATA / f"{scene}.json").read_text())
    data["film"] = {"width": 24, "height": 18}
    cs = compile_scene(load_scene(data, allow_paths=True, base_dir=DATA))
    assert unsupported(cs) is None
    assert_same_buffer(*both(cs, sample_count=4))


def test_max_depth_and_adaptive_masks_agree_with_the_scalar_kernel():
    cs = compile_scene(load_scene(example("glass_sphere", max_depth=2)))
    active = (np.arange(cs.width * cs.height).reshape(cs.height, cs.width) % 3 != 0)
    scalar, wave = both(cs, sample_count=5, active=active.astype(np.uint8))
    assert_same_buffer(scalar, wave)
    assert wave.count[~active].sum() == 0


def test_deterministic_and_independent_of_tiles_passes_and_batches():
    """A sample is a function of (seed, pixel, index): the frame whole, cut into uneven tiles and
    sample ranges, and traced in batches of one pixel are the same image to float64 addition
    order; two runs are the same bit for bit."""
    cs = compile_scene(load_scene(example("cornell_box", spp=9)))
    ones = np.ones((cs.height, cs.width), np.uint8)
    whole = render_tile_wavefront(cs, 0, 0, cs.width, cs.height, 0, 9, ones)
    again = render_tile_wavefront(cs, 0, 0, cs.width, cs.height, 0, 9, ones)
    np.testing.assert_array_equal(whole.sum, again.sum)
    tiny = render_tile_wavefront(cs, 0, 0, cs.width, cs.height, 0, 9, ones, batch_paths=5)
    np.testing.assert_array_equal(whole.sum, tiny.sum)  # whole pixels a batch: same order
    tiled = SampleBuffer.empty(0, 0, cs.width, cs.height)
    xs, ys = [0, 7, 16, 24], [0, 5, 18]
    for y0, y1 in zip(ys[:-1], ys[1:], strict=True):
        for x0, x1 in zip(xs[:-1], xs[1:], strict=True):
            for s0, s1 in ((0, 4), (4, 9)):
                tiled.add(render_tile(cs, x0, y0, x1 - x0, y1 - y0, s0, s1 - s0,
                                      kernel="wavefront"))
    assert_same_buffer(whole, tiled)


def test_a_scene_beyond_the_surface_materials_falls_back_to_the_scalar_kernel():
    cs = compile_scene(load_scene(example("translucent_sphere", width=8, height=6)))
    assert "material kinds" in unsupported(cs)
    a = render_tile(cs, 0, 0, 8, 6, 0, 2, kernel="scalar")
    b = render_tile(cs, 0, 0, 8, 6, 0, 2, kernel="wavefront")
    np.testing.assert_array_equal(a.sum, b.sum)
    sobol = compile_scene(load_scene(example("cornell_box", sampler="sobol")))
    assert unsupported(sobol) == "the sobol sampler"
    # The gpu kernel renders every scene on the GPU (test_gpu.py, on the simulator): where no
    # GPU is seen it is refused, naming why, not run on the CPU unasked
    if gpu_missing() is not None:
        with pytest.raises(RuntimeError, match="the gpu kernel: "):
            render_tile(cs, 0, 0, 8, 6, 0, 2, kernel="gpu")
    with pytest.raises(ValueError, match="kernel"):
        render_tile(cs, 0, 0, 8, 6, 0, 2, kernel="vulkan")


def test_textures_and_shading_normals_fall_back_to_the_scalar_kernel():
    """The stages read a material's untextured row and the geometric normal: a textured
    material, or a mesh with shading normals, is rendered by the scalar kernel."""
    scene = example("cornell_box", width=8, height=6)
    first = next(iter(scene["materials"]))
    scene["materials"][first] = {"type": "diffuse", "albedo": {
        "type": "checkerboard", "color0": [0.8, 0.2, 0.2], "color1": [0.1, 0.1, 0.6]}}
    cs = compile_scene(load_scene(scene))
    assert unsupported(cs) == "textured materials"
    a = render_tile(cs, 0, 0, 8, 6, 0, 2, kernel="scalar")
    b = render_tile(cs, 0, 0, 8, 6, 0, 2, kernel="wavefront")
    np.testing.assert_array_equal(a.sum, b.sum)
    smooth = example("cornell_box", width=8, height=6)
    smooth["objects"].append({
        "type": "mesh", "material": first,
        "vertices": [[-0.3, 0.1, -0.3], [0.3, 0.1, -0.3], [0.0, 0.5, -0.2]],
        "triangles": [[0, 1, 2]], "normals": [[0, 0.2, 1], [0.2, 0, 1], [-0.2, 0, 1]]})
    assert unsupported(compile_scene(load_scene(smooth))) == "shading normals"


def test_cornell_box_error_against_the_mitsuba_reference():
    """At the reference's size and 64 spp the wavefront image's MSE against the converged
    Mitsuba 3 reference is the scalar kernel's (same paths) and within the bound the scalar
    kernel's own test holds it to: 1.25× Mitsuba's at equal spp (seed 1 against the mean of
    Mitsuba's four 64 spp images)."""
    ref = np.load(DATA / "cornell_box_ref.npy").astype(np.float64)
    h, w = ref.shape[:2]
    data = example("cornell_box", width=w, height=h, spp=64, seed=1)
    wave = render(data, kernel="wavefront").astype(np.float64)
    scalar = render(data, kernel="scalar").astype(np.float64)
    mitsuba = np.mean([np.mean((np.load(DATA / f"cornell_box_spp64_seed{k}.npy") - ref) ** 2)
                       for k in range(1, 5)])
    mse = np.mean((wave - ref) ** 2)
    assert mse == pytest.approx(np.mean((scalar - ref) ** 2), rel=1e-6)
    assert mse <= 1.25 * mitsuba, (mse, mitsuba)
    np.testing.assert_allclose(wave.mean(axis=(0, 1)), ref.mean(axis=(0, 1)), rtol=0.03)


@pytest.mark.parametrize(("material", "inside"), [
    ({"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}, 0.5),
    ({"type": "dielectric", "ior": 1.5}, 1.0),
    ({"type": "mirror", "reflectance": [1, 1, 1]}, 1.0),
])
def test_white_furnace(material, inside):
    """A convex object under a uniform background of radiance 1 and no other light: light that
    leaves it never returns, so a Lambertian sphere of albedo a shows a (one bounce), and
    lossless glass or a perfect mirror shows 1 (every path escapes with its whole energy). The
    estimate is unbiased with NEE, MIS and roulette; 2 % of the mean over the sphere's 150-odd
    pixels × 64 samples is several standard errors, while a lost MIS weight or light sample
    moves the diffuse sphere by 30 % or more."""
    data = {
        "camera": {"position": [0, 0, 3], "look_at": [0, 0, 0], "fov": 40},
        "film": {"width": 16, "height": 16},
        "render": {"spp": 64, "max_depth": -1, "seed": 5},
        "background": [1, 1, 1],
        "materials": {"m": material},
        "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 0.8, "material": "m"}],
    }
    img = render(data, kernel="wavefront")
    yy, xx = np.mgrid[:16, :16]
    on = (xx - 7.5) ** 2 + (yy - 7.5) ** 2 < 4.0**2  # well inside the sphere's silhouette
    off = (xx - 7.5) ** 2 + (yy - 7.5) ** 2 > 7.5**2
    assert on.sum() > 40
    np.testing.assert_allclose(img[off], 1.0, rtol=1e-12)
    np.testing.assert_allclose(img[on].mean(axis=0), inside, rtol=0.02)


# --- each stage against plain NumPy --------------------------------------------------------------

def test_generate_stage_against_numpy():
    cs = compile_scene(load_scene(example("cornell_box", width=10, height=7)))
    S = cs.arrays
    # a count a pixel (adaptive sampling): 3, 1 or 2 samples, none for one pixel
    counts = np.resize(np.array([3, 1, 2], np.int32), 20).reshape(4, 5)
    counts[1, 2] = 0
    work, first, batches = batching(counts, 1 << 16)
    np.testing.assert_array_equal(work, np.flatnonzero(counts.ravel()))
    assert batches == [(0, len(work))] and first[-1] == counts.sum()
    n = int(first[-1])
    P = path_state(n)
    live = np.empty(n, np.int64)
    generate(S, P, cs.width, cs.height, cs.seed, 2, 3, 5, work, first, 11, 0, n, live, 2)
    np.testing.assert_array_equal(live, np.arange(n))
    per = counts.ravel()[work]
    slot = np.repeat(work, per)
    x, y = 2 + slot % 5, 3 + slot // 5
    s = 11 + np.concatenate([np.arange(k) for k in per])
    np.testing.assert_array_equal(P.sample, s)
    keys = np.array([sample_key(cs.seed, int(py) * cs.width + int(px), int(k))
                     for px, py, k in zip(x, y, s, strict=True)], np.uint64)
    np.testing.assert_array_equal(P.key, keys)
    jx = np.array([uniform(k, 0) for k in keys])
    jy = np.array([uniform(k, 1) for k in keys])
    cam = S.camera
    sx = (2 * (x + jx) / cs.width - 1) * cam[12] * cam[13]
    sy = (1 - 2 * (y + jy) / cs.height) * cam[12]
    d = cam[3:6] + sx[:, None] * cam[6:9] + sy[:, None] * cam[9:12]
    d /= np.linalg.norm(d, axis=1)[:, None]
    np.testing.assert_allclose(P.d, d, rtol=1e-14, atol=1e-15)
    np.testing.assert_array_equal(P.o, np.broadcast_to(cam[:3], (n, 3)))
    assert (P.alive == 1).all() and (P.beta == 1).all() and (P.L == 0).all()


def numpy_closest(kind, geo, o, d):
    """Closest hit of each ray among spheres and parallelograms/triangles, by brute force."""
    from renderer.geometry.shapes import SPHERE, TRIANGLE

    best = np.full(len(o), np.inf)
    prim = np.full(len(o), -1)
    for k in range(len(kind)):
        g = geo[k]
        if kind[k] == SPHERE:
            oc = o - g[:3]
            b = np.einsum("ij,ij->i", oc, d)
            c = np.einsum("ij,ij->i", oc, oc) - g[3] ** 2
            disc = b * b - c
            root = np.sqrt(np.maximum(disc, 0))
            t0, t1 = -b - root, -b + root
            t = np.where(t0 > 0, t0, t1)
            t = np.where((disc >= 0) & (t > 0), t, np.inf)
        else:
            e1, e2 = g[3:6], g[6:9]
            p = np.cross(d, e2)
            det = p @ e1
            tv = o - g[:3]
            u = np.einsum("ij,ij->i", tv, p) / det
            q = np.cross(tv, e1)
            v = np.einsum("ij,ij->i", q, d) / det
            t = (q @ e2) / det
            far = u + v if kind[k] == TRIANGLE else v
            ok = (det != 0) & (u >= 0) & (u <= 1) & (v >= 0) & (far <= 1) & (t > 0)
            t = np.where(ok, t, np.inf)
        closer = t < best
        best[closer] = t[closer]
        prim[closer] = k
    return best, prim


@pytest.mark.parametrize("scene", ["cornell_box", "surface"])
def test_intersect_stage_against_numpy(scene):
    """Random rays from inside the scene: the stage's closest hits are the brute-force NumPy
    ones (a flat scene, and one searched with the BVH)."""
    data = SURFACE_SCENE if scene == "surface" else example("cornell_box")
    cs = compile_scene(load_scene(data))
    S = cs.arrays
    rng = np.random.default_rng(7)
    n = 4000
    P = path_state(n)
    P.o[:] = rng.uniform(-0.9, 0.9, (n, 3))
    d = rng.normal(size=(n, 3))
    P.d[:] = d / np.linalg.norm(d, axis=1)[:, None]
    live = rng.permutation(n)[: n - 100]
    intersect(S, P, live, len(live), cs.stack_size, 2)
    t, prim = numpy_closest(S.prim_kind, S.prim_geo, P.o[live], P.d[live])
    np.testing.assert_allclose(P.hit_t[live], t, rtol=1e-9)
    # Coplanar faces tie (the boxes' bottoms lie in the floor: a ray that hits the floor under a
    # box hits both at the same distance, and whichever is tested first wins); the rest agree
    differ = P.hit_prim[live] != prim
    assert differ.mean() < 0.01
    np.testing.assert_allclose(P.hit_t[live][differ], t[differ], rtol=1e-14)
    stack = traversal_stack(cs.stack_size)
    i = live[0]
    assert P.hit_t[i] == intersect_closest(S.bvh_lo, S.bvh_hi, S.bvh_child, S.bvh_count, S.flat,
                                           S.prim_kind, S.prim_geo, P.o[i], P.d[i], math.inf,
                                           stack)[0]


def test_compact_and_accumulate_stages_against_numpy():
    rng = np.random.default_rng(3)
    n, tile_w = 48, 5
    P = path_state(n)
    P.alive[:] = rng.random(n) < 0.4
    live = rng.permutation(n)
    k = compact(P, live.copy(), n)
    kept = live[P.alive[live] == 1]
    assert k == len(kept)
    out = live.copy()
    compact(P, out, n)
    np.testing.assert_array_equal(out[:k], kept)

    work = np.array([0, 2, 3, 5, 6, 7, 9, 11, 12, 14, 15, 16, 17, 18, 19], np.int64)
    per = np.array([4, 4, 5, 3, 4, 4, 6, 2, 4, 4, 4, 4, 4, 4, 4])  # a count a pixel
    first = np.concatenate([[0], np.cumsum(per)])
    P.L[:] = rng.exponential(size=(n, 3))
    P.L[13, 1] = np.inf
    P.L[14, 0] = 1e200  # its square overflows: dropped as the scalar kernel drops it
    buf = SampleBuffer.empty(0, 0, tile_w, 4)
    # the batch: pixels 2 … 13 of the work's 15, its paths 8 … 55 of 60 in slots 0 … 47
    w0, w1 = 2, 14
    g0 = int(first[w0])
    assert (g0, int(first[w1]) - g0) == (8, n)
    accumulate(P, w0, w1, first, work, buf.sum, buf.sum_sq, buf.count, buf.dropped, tile_w)
    want = np.zeros((4, tile_w, 3))
    want_sq = np.zeros((4, tile_w, 3))
    count = np.zeros((4, tile_w), np.int64)
    dropped = np.zeros((4, tile_w), np.int64)
    for i in range(n):
        slot = work[np.searchsorted(first, g0 + i, side="right") - 1]
        r, c = divmod(slot, tile_w)
        with np.errstate(over="ignore"):
            finite = np.isfinite(P.L[i] ** 2).all()
        if finite:
            want[r, c] += P.L[i]
            want_sq[r, c] += P.L[i] ** 2
            count[r, c] += 1
        else:
            dropped[r, c] += 1
    np.testing.assert_allclose(buf.sum, want, rtol=1e-12)
    np.testing.assert_allclose(buf.sum_sq, want_sq, rtol=1e-12)
    np.testing.assert_array_equal(buf.count, count)
    np.testing.assert_array_equal(buf.dropped, dropped)
    assert dropped.sum() == 2
