"""Sample buffers and tiling: an image must not depend on how the frame is cut up."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from renderer.film.buffer import MAGIC, SampleBuffer
from renderer.integrators.path import render_tile_kernel
from renderer.jit import run_chunks
from renderer.render import render, render_buffer, render_tile
from renderer.scene import load_scene
from renderer.scene.compile import compile_scene

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"


def small(name: str, width=42, height=30, **render_settings) -> dict:
    data = json.loads((EXAMPLES / name).read_text())
    data["film"] = {"width": width, "height": height}
    data["render"].update(render_settings)
    return data


@pytest.fixture(scope="module", params=["independent", "sobol"])
def glass(request):
    return compile_scene(load_scene(small("glass_sphere.json", spp=12, sampler=request.param)))


def test_tiles_and_passes_add_up_to_the_whole(glass):
    """The frame rendered whole, as 7×5 uneven tiles, and as three sample ranges is the same image:
    every sample is a function of (seed, pixel, index) alone. Only the order of float64 additions
    differs, hence 1e-12 relative."""
    whole = render_tile(glass, 0, 0, glass.width, glass.height, 0, glass.spp)
    xs = np.linspace(0, glass.width, 8).astype(int)
    ys = np.linspace(0, glass.height, 6).astype(int)
    tiled = SampleBuffer.empty(0, 0, glass.width, glass.height)
    for y0, y1 in zip(ys[:-1], ys[1:], strict=True):
        for x0, x1 in zip(xs[:-1], xs[1:], strict=True):
            for s0, s1 in ((0, 5), (5, 7), (7, 12)):
                tiled.add(render_tile(glass, x0, y0, x1 - x0, y1 - y0, s0, s1 - s0))
    np.testing.assert_array_equal(tiled.count, whole.count)
    np.testing.assert_allclose(tiled.sum, whole.sum, rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(tiled.sum_sq, whole.sum_sq, rtol=1e-12, atol=1e-300)
    assert whole.count.min() == glass.spp


@pytest.mark.parametrize("n_threads", [2, 3, 7, 64])
def test_the_split_among_threads_does_not_change_the_image(glass, n_threads):
    """render_tile_kernel deals rows out in turn to n_threads chunks (more chunks than rows, or
    than numba has threads, included): every pixel's sums come out bit for bit as with one."""
    def run(n):
        buf = SampleBuffer.empty(0, 0, glass.width, glass.height)
        render_tile_kernel(
            glass.arrays, glass.width, glass.height, glass.seed, glass.max_depth,
            glass.stack_size, 0, 0, glass.width, glass.height, 0, 4,
            np.full((glass.height, glass.width), 4, np.int32), buf.sum, buf.sum_sq, buf.count,
            buf.dropped, buf.segments, n)
        return buf

    one, many = run(1), run(n_threads)
    np.testing.assert_array_equal(many.sum, one.sum)
    np.testing.assert_array_equal(many.sum_sq, one.sum_sq)
    np.testing.assert_array_equal(many.count, np.full((glass.height, glass.width), 4))


def test_run_chunks_waits_for_every_chunk_and_raises_the_first_error():
    """The row threads write into the caller's arrays: run_chunks returns (or raises) only once
    every chunk has ended, whichever one failed."""
    ended = []

    def chunk(c):
        if c == 1:
            raise ValueError("chunk 1")
        time.sleep(0.05 * c)
        ended.append(c)

    with pytest.raises(ValueError, match="chunk 1"):
        run_chunks(chunk, 4)
    assert sorted(ended) == [0, 2, 3]


FORKED = """
import os, signal
import numpy as np
from renderer.scene import load_scene
from renderer.scene.compile import compile_scene
cs = compile_scene(load_scene({
    "camera": {"position": [0, 0, 3], "look_at": [0, 0, 0], "fov": 40},
    "film": {"width": 8, "height": 8}, "render": {"spp": 2, "max_depth": 2, "seed": 1},
    "materials": {"m": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
    "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 0.5, "material": "m"}],
    "lights": [{"type": "point", "position": [0, 2, 2], "intensity": [5, 5, 5]}]}))
from renderer.integrators.path import render_tile_kernel
from renderer.film.buffer import SampleBuffer

def run():
    buf = SampleBuffer.empty(0, 0, 8, 8)
    render_tile_kernel(cs.arrays, 8, 8, cs.seed, cs.max_depth, cs.stack_size, 0, 0, 8, 8, 0, 2,
                       np.full((8, 8), 2, np.int32), buf.sum, buf.sum_sq, buf.count,
                       buf.dropped, buf.segments, 2)
    return int(buf.count.sum())

assert run() == 128  # the parent's pool of threads exists now
pid = os.fork()
if pid == 0:
    signal.alarm(60)  # a child left with its parent's pool would wait for ever
    os._exit(0 if run() == 128 else 3)
_, status = os.waitpid(pid, 0)
print(os.waitstatus_to_exitcode(status))
"""


def test_a_forked_child_renders_on_threads_of_its_own(tmp_path):
    """A prefork worker forks after its parent may have rendered: the child's copy of the
    parent's thread pool has no threads, so run_chunks makes the child a pool of its own (with
    the parent's, the child's rows would wait for ever: here, until the alarm kills it)."""
    out = subprocess.run([sys.executable, "-c", FORKED], cwd=ROOT, capture_output=True,
                         text=True, timeout=300, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split()[-1] == "0", out.stdout


def test_buffers_merge_by_addition_in_any_order(glass):
    a = render_tile(glass, 4, 3, 10, 8, 0, 3)
    b = render_tile(glass, 4, 3, 10, 8, 3, 4)
    ab, ba = a + b, b + a
    np.testing.assert_allclose(ab.sum, ba.sum, rtol=1e-15)
    np.testing.assert_array_equal(ab.count, np.full((8, 10), 7))
    both = render_tile(glass, 4, 3, 10, 8, 0, 7)
    np.testing.assert_allclose(ab.sum, both.sum, rtol=1e-12, atol=1e-300)


def test_buffer_serialization_round_trip(glass):
    a = render_tile(glass, 1, 2, 5, 4, 0, 2)
    b = SampleBuffer.from_bytes(a.to_bytes())
    assert (b.x0, b.y0) == (1, 2)
    for name in ("sum", "sum_sq", "count", "dropped"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        assert getattr(b, name).dtype == getattr(a, name).dtype
        assert getattr(b, name).flags.writeable  # the merger adds into it
    # The layout is the documented one: header, then the raw little-endian arrays.
    data = a.to_bytes()
    assert data[:8] == MAGIC and len(data) == 24 + 4 * 5 * (3 * 8 + 3 * 8 + 8 + 8)
    assert np.frombuffer(data, "<i4", 4, 8).tolist() == [1, 2, 4, 5]
    np.testing.assert_array_equal(np.frombuffer(data, "<f8", 60, 24).reshape(4, 5, 3), a.sum)
    b.add(a)  # writable: merging into a decoded buffer works
    np.testing.assert_array_equal(b.count, 2 * a.count)


def test_buffers_stored_as_npz_by_earlier_versions_are_still_read(glass):
    a = render_tile(glass, 1, 2, 5, 4, 0, 2)
    out = io.BytesIO()
    np.savez(out, origin=np.array([1, 2]), sum=a.sum, sum_sq=a.sum_sq, count=a.count,
             dropped=a.dropped)
    b = SampleBuffer.from_bytes(out.getvalue())
    assert (b.x0, b.y0) == (1, 2)
    np.testing.assert_array_equal(b.sum, a.sum)
    np.testing.assert_array_equal(b.count, a.count)


@pytest.mark.parametrize("cut", [0, 7, 23, 24, 100, -1])
def test_a_truncated_or_foreign_buffer_is_a_value_error(glass, cut):
    data = render_tile(glass, 1, 2, 5, 4, 0, 2).to_bytes()
    with pytest.raises(ValueError):
        SampleBuffer.from_bytes(data[:cut] if cut >= 0 else data + b"x")
    with pytest.raises(ValueError):
        SampleBuffer.from_bytes(b"\x93NUMPY" + data[8:])  # a bare .npy or anything else


def test_tile_outside_the_frame_is_refused(glass):
    with pytest.raises(ValueError, match="outside"):
        render_tile(glass, glass.width - 2, 0, 4, 4, 0, 1)


def test_seed_changes_the_noise_not_the_image():
    a = render(small("cornell_box.json", 24, 18, spp=8, seed=1))
    b = render(small("cornell_box.json", 24, 18, spp=8, seed=2))
    c = render(small("cornell_box.json", 24, 18, spp=8, seed=1))
    np.testing.assert_array_equal(a, c)
    assert not np.array_equal(a, b)
    # Same expectation: the frame means agree to well within their noise (~1 % here)
    assert abs(a.mean() - b.mean()) < 0.05 * a.mean()


def test_variance_estimate_matches_the_spread_of_independent_renders():
    """variance_of_mean() from one render predicts the scatter between renders with other seeds.

    Over 16 seeds the sample variance of the pixel means has relative error ~ √(2/15) ≈ 0.37 per
    pixel; averaged over ~400 lit pixels the ratio is within ~5 % of 1 (measured: 1.02), so
    [0.8, 1.25] is a loose bound that still catches a missing 1/n (a factor 64) or a biased
    estimator. At 16 spp the per-pixel variance estimates are too heavy-tailed for this (the ratio
    drifts to ~0.75), hence 64 spp.
    """
    scenes = [compile_scene(load_scene(small("cornell_box.json", 24, 18, spp=64, seed=s)))
              for s in range(16)]
    bufs = [render_buffer(cs) for cs in scenes]
    means = np.stack([b.sum / b.count[..., None] for b in bufs])
    observed = means.var(axis=0, ddof=1)
    predicted = np.mean([b.variance_of_mean() for b in bufs], axis=0)
    lit = predicted > 1e-8
    ratio = observed[lit].mean() / predicted[lit].mean()
    assert 0.8 < ratio < 1.25, ratio


@pytest.mark.parametrize("scale,shift", [(1e-4, 0.0), (1e4, 0.0), (1.0, 1e5), (1e3, -3e6)])
def test_images_do_not_depend_on_scene_scale_or_position(scale, shift):
    """Scaling a scene (and moving it far from the origin) must not change its image: area-light
    radiance is scale-free and the camera sees the same angles. Self-intersection artefacts (shadow
    acne, light leaking through a wall) would darken or speckle the image at some scale.

    The same samples trace the same paths, up to rounding and the origin offset (1e-9 of the
    coordinates, so 1e-4 at 1e5 from the origin: relative changes of ~1e-4 in shadow-ray lengths),
    which can flip a few random decisions. So the frame mean must agree to 0.5 % (its noise is ~1 %,
    but most paths are the same) and 95 % of pixels to 1e-3 relative. Before the shadow ray's
    length was measured from its lifted origin, the floor 1e5 away from the origin went black.
    """
    data = small("glass_sphere.json", 32, 24, spp=8)
    ref = render(data)

    def move(p):
        return [c * scale + shift for c in p]

    def vec(v):
        return [c * scale for c in v]

    data["camera"]["position"] = move(data["camera"]["position"])
    data["camera"]["look_at"] = move(data["camera"]["look_at"])
    for obj in data["objects"]:
        if obj["type"] == "sphere":
            obj["center"] = move(obj["center"])
            obj["radius"] *= scale
        else:
            obj["origin"] = move(obj["origin"])
            obj["edge1"] = vec(obj["edge1"])
            obj["edge2"] = vec(obj["edge2"])
    # Absorption is per unit length
    glass = data["materials"]["tinted_glass"]
    glass["absorption"] = [a / scale for a in glass["absorption"]]
    img = render(data)
    assert abs(img.mean() - ref.mean()) < 5e-3 * ref.mean()
    close = np.isclose(img, ref, rtol=1e-3, atol=1e-6).all(axis=-1)
    assert close.mean() > 0.95, close.mean()


@pytest.mark.parametrize("name", ["cornell_box.json", "translucent_sphere.json",
                                  "glass_sphere.json"])
def test_a_small_scene_renders_the_same_flat_as_with_a_tree(name, monkeypatch):
    """Scenes of at most FLAT_MAX primitives are searched flat (renderer/geometry/flat.py), not
    with the BVH; both find the same hits, so the image is bit for bit the same (these scenes
    have one light and no coplanar faces that tie)."""
    import renderer.scene.compile as compile_module

    scene = load_scene(small(name, width=24, height=18, spp=4))
    flat = compile_scene(scene)
    assert flat.info["flat"] and flat.info["bvh_nodes"] == 0
    monkeypatch.setattr(compile_module, "FLAT_MAX", 0)
    tree = compile_scene(scene)
    assert not tree.info["flat"] and tree.info["bvh_nodes"] > 0
    assert tree.arrays.flat.shape[1] == 0
    # the scalar kernel's flat search and tree (the packet kernel has no tree)
    a = render_tile(flat, 0, 0, flat.width, flat.height, 0, flat.spp, kernel="scalar")
    b = render_tile(tree, 0, 0, tree.width, tree.height, 0, tree.spp, kernel="scalar")
    np.testing.assert_array_equal(a.sum, b.sum)
    np.testing.assert_array_equal(a.count, b.count)
