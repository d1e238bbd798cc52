"""The packet kernel (16 paths in the vector lanes, float32) against Mitsuba 3's reference, the
scalar kernel and closed forms; the scenes it leaves to the scalar kernel."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numba
import numpy as np
import pytest
from scipy import stats

from renderer.packet import (
    cosine_direction,
    exp32,
    hg_direction,
    hg_pdf32,
    log32,
    render_tile_packet,
    reverse32,
    sin_cos_quarter,
    sobol_pair32,
    unsupported,
)
from renderer.render import render, render_buffer, render_tile
from renderer.rng import sobol_value
from renderer.scene import load_scene
from renderer.scene.compile import compile_scene

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
DATA = ROOT / "tests" / "data"


def cornell(width=24, height=18, **render_settings) -> dict:
    data = json.loads((EXAMPLES / "cornell_box.json").read_text())
    data["film"] = {"width": width, "height": height}
    data["render"].update(render_settings)
    return data


def compiled(data: dict):
    return compile_scene(load_scene(data))


def test_cornell_box_error_against_the_mitsuba_reference():
    """At the reference's size and 64 spp, the packet images' MSE against the converged Mitsuba 3
    reference, over seeds 1–4, is within the bound the scalar kernel's test holds it to: 1.25×
    Mitsuba's own (the mean of its four 64-spp images; over ten seeds both kernels come out at
    0.95–1.03 of it, one seed 0.65–1.5). Each image's mean lies within 3 % of the reference's (a
    lost MIS weight or light pdf moves it by 30 % or more)."""
    ref = np.load(DATA / "cornell_box_ref.npy").astype(np.float64)
    h, w = ref.shape[:2]
    assert unsupported(compiled(cornell(w, h))) is None
    mitsuba = np.mean([np.mean((np.load(DATA / f"cornell_box_spp64_seed{k}.npy") - ref) ** 2)
                       for k in range(1, 5)])
    errors = []
    for seed in range(1, 5):
        packet = render(cornell(w, h, spp=64, seed=seed), kernel="packet").astype(np.float64)
        errors.append(np.mean((packet - ref) ** 2))
        np.testing.assert_allclose(packet.mean(axis=(0, 1)), ref.mean(axis=(0, 1)), rtol=0.03)
    assert np.mean(errors) <= 1.25 * mitsuba, (errors, mitsuba)


def test_the_sobol_sampler_against_the_mitsuba_reference():
    """Under ``render.sampler: sobol`` (the first two vertices' light and direction samples
    stratified, as the scalar kernel's), the 64-spp images of seeds 1–4 have a mean within 3 % of
    the reference's and an MSE below 0.053 of Mitsuba 3's independent sampler's: the packet
    kernel measures 0.047 of it on these seeds, the scalar kernel 0.047 over eight (under the
    independent sampler both 0.95). Two samples of a pixel sharing a point measured 0.057, the
    second vertex reading the first's sequences 0.061."""
    ref = np.load(DATA / "cornell_box_ref.npy").astype(np.float64)
    h, w = ref.shape[:2]
    assert unsupported(compiled(cornell(w, h, sampler="sobol"))) is None
    mitsuba = np.mean([np.mean((np.load(DATA / f"cornell_box_spp64_seed{k}.npy") - ref) ** 2)
                       for k in range(1, 5)])
    errors = []
    for seed in range(1, 5):
        img = render(cornell(w, h, spp=64, seed=seed, sampler="sobol"),
                     kernel="packet").astype(np.float64)
        errors.append(np.mean((img - ref) ** 2))
        np.testing.assert_allclose(img.mean(axis=(0, 1)), ref.mean(axis=(0, 1)), rtol=0.03)
    assert np.mean(errors) <= 0.053 * mitsuba, (np.array(errors) / mitsuba)


def test_sobol_pair32_is_the_scalar_kernels_sequence():
    """The 32-bit lanes' (0,2)-sequence point is ``renderer.rng.sobol_value``'s (itself checked
    against Burley's construction bit for bit and for the (0,m,2)-net property in test_rng.py),
    rounded down to float32's 24 bits, over random indices and seeds."""
    rng = np.random.default_rng(11)
    pair = np.vectorize(lambda i, a, b, c: sobol_pair32(
        reverse32.py_func(np.uint32(i)), np.uint32(a), np.uint32(b), np.uint32(c)))
    i, a, b, c = (rng.integers(0, 2 ** 32, 3000, dtype=np.uint64) for _ in range(4))
    i[:40] = np.arange(40)  # the first points of a pixel's sequence
    u0, u1 = pair(i, a, b, c)
    x0 = np.array([sobol_value(*args, 0) for args in zip(i, a, b, strict=True)])
    x1 = np.array([sobol_value(*args, 1) for args in zip(i, a, c, strict=True)])
    for u, x in ((u0, x0), (u1, x1)):
        assert ((x - u >= 0) & (x - u < 2.0 ** -24)).all()


def assert_same_means(a, b) -> None:
    """Two buffers of one frame estimate the same image: each channel's mean over the frame and
    over its upper and lower halves agree within 4.5 standard errors of the difference (each
    buffer's from its pixels' sample variances)."""
    half = a.sum.shape[0] // 2
    for rows in (slice(None), slice(0, half), slice(half, None)):
        means, errors = [], []
        for buf in (a, b):
            mean = buf.sum[rows] / buf.count[rows][..., None]
            var = buf.variance_of_mean()[rows]
            means.append(mean.mean(axis=(0, 1)))
            errors.append(np.sqrt(var.sum(axis=(0, 1))) / (mean.shape[0] * mean.shape[1]))
        diff = np.abs(means[0] - means[1])
        assert (diff <= 4.5 * np.hypot(errors[0], errors[1])).all(), (rows, means, errors)


def two_lights(max_depth: int, sampler: str = "independent") -> dict:
    """The Cornell box with its light cut into two triangles and a second, dimmer and bluer
    light on the back wall: light picked by power, triangles hit and sampled, a depth limit."""
    data = cornell(16, 12, spp=64, seed=3, max_depth=max_depth, sampler=sampler)
    objects = [o for o in data["objects"] if "emission" not in o]
    light = {"material": "light", "emission": [17, 12, 4]}
    a, b, c, d = [-0.25, 0.99, -0.25], [0.25, 0.99, -0.25], [0.25, 0.99, 0.25], [-0.25, 0.99, 0.25]
    objects.append({"type": "mesh", "vertices": [a, b, c, d], "triangles": [[0, 1, 2], [0, 2, 3]],
                    **light})
    objects.append({"type": "quad", "origin": [-0.2, 0.3, -0.99], "edge1": [0.4, 0, 0],
                    "edge2": [0, 0.3, 0], "material": "light", "emission": [1, 2, 6]})
    data["objects"] = objects
    return data


@pytest.mark.parametrize(("max_depth", "sampler"),
                         [(-1, "independent"), (1, "independent"), (3, "independent"),
                          (-1, "sobol")])
def test_two_lights_and_triangles_agree_with_the_scalar_kernel(max_depth, sampler):
    """Both kernels estimate the same image: each channel's frame mean agrees within 4.5
    standard errors of the difference (each kernel's from its pixels' sample variances, which
    overstate a stratified sampler's), and so do the means of the image's upper and lower
    halves. Under the sobol sampler the light pick is stratified too."""
    cs = compiled(two_lights(max_depth, sampler))
    assert unsupported(cs) is None
    assert len(cs.arrays.light_kind) == 3
    a = render_buffer(cs, 256, kernel="packet")
    b = render_buffer(cs, 256, kernel="scalar")
    assert_same_means(a, b)
    assert (a.count == 256).all() and not a.dropped.any()


def test_depth_zero_shows_only_what_the_camera_sees():
    """max_depth 0: the light's own radiance where the camera sees it, black elsewhere (no
    light sample, no bounce): each pixel is k/4 of the emission, k of its 4 samples on the
    light."""
    data = cornell(32, 24, spp=4, max_depth=0)
    img = render(data, kernel="packet").astype(np.float64)
    share = img / np.array([17.0, 12.0, 4.0])
    lit = share.max(axis=-1) > 0
    assert lit.any() and lit.mean() < 0.05 and (share[lit] == 1.0).all(axis=-1).any()
    np.testing.assert_allclose(share, share[..., :1].repeat(3, axis=-1), rtol=1e-6)
    np.testing.assert_allclose(4 * share, np.round(4 * share), atol=1e-5)


@pytest.mark.parametrize("sampler", ["independent", "sobol"])
def test_a_tile_is_the_frame_cut_anywhere_into_tiles_and_passes(sampler):
    """Every path starts from its sample's key (seed, pixel, global index) and, under the sobol
    sampler, its pixel's sequences: the frame in one call, and the same frame as four tiles of
    two passes each, are the same paths (the sums agree to float64 rounding: a pixel's samples
    are added in the order their lanes finish, which the packets' make-up decides); another seed
    is not."""
    cs = compiled(cornell(20, 14, spp=8, seed=4, sampler=sampler))
    whole = render_tile(cs, 0, 0, 20, 14, 0, 8, kernel="packet")
    for x0, y0, w, h in ((0, 0, 13, 5), (13, 0, 7, 5), (0, 5, 13, 9), (13, 5, 7, 9)):
        parts = render_tile(cs, x0, y0, w, h, 0, 3, kernel="packet")
        parts.add(render_tile(cs, x0, y0, w, h, 3, 5, kernel="packet"))
        window = (slice(y0, y0 + h), slice(x0, x0 + w))
        np.testing.assert_allclose(parts.sum, whole.sum[window], rtol=1e-12, atol=0)
        np.testing.assert_allclose(parts.sum_sq, whole.sum_sq[window], rtol=1e-12, atol=0)
        np.testing.assert_array_equal(parts.count, whole.count[window])
    other = compiled(cornell(20, 14, spp=8, seed=5, sampler=sampler))
    assert not np.array_equal(render_tile(other, 0, 0, 20, 14, 0, 8, kernel="packet").sum,
                              whole.sum)


def test_each_pixel_takes_its_own_count():
    """Adaptive sampling's per-pixel counts: each pixel gets exactly its count (0 included),
    its path segments are counted, and its samples are the first of the range (a pixel given
    3 has the sums of a pass of 3, to float64 rounding)."""
    cs = compiled(cornell(9, 7, spp=1))
    counts = np.arange(63, dtype=np.int32).reshape(7, 9) % 5
    buf = render_tile_packet(cs, 0, 0, 9, 7, 10, counts)
    np.testing.assert_array_equal(buf.count + buf.dropped, counts)
    assert (buf.segments[counts > 0] >= counts[counts > 0]).all()
    assert not buf.segments[counts == 0].any()
    three = render_tile_packet(cs, 0, 0, 9, 7, 10, np.full((7, 9), 3, np.int32))
    np.testing.assert_allclose(buf.sum[counts == 3], three.sum[counts == 3], rtol=1e-12, atol=0)


def test_a_scenes_coverage_and_columns_are_worked_out_once(monkeypatch):
    """Every pass asks whether the packet kernel covers the scene and takes its primitive
    columns: each is computed once for a compiled scene's arrays (not again each pass), and again
    for a copy of the scene with other arrays; the passes' sums are unchanged."""
    import dataclasses

    import renderer.packet as packet
    import renderer.render as render_module

    calls = {"covers": 0, "columns": 0}

    def counted(key, fn):
        def wrapper(scene):
            calls[key] += 1
            return fn(scene)
        return wrapper

    monkeypatch.setattr(render_module, "packet_unsupported", counted("covers", unsupported))
    monkeypatch.setattr(packet, "prim_columns", counted("columns", packet.prim_columns))
    cs = compiled(cornell(8, 6, spp=4))
    first = render_tile(cs, 0, 0, 8, 6, 0, 4, kernel="packet")
    again = render_tile(cs, 0, 0, 8, 6, 0, 4, kernel="packet")
    np.testing.assert_array_equal(first.sum, again.sum)
    assert calls == {"covers": 1, "columns": 1}
    flat = np.array(cs.arrays.prim_geo)
    copy = dataclasses.replace(cs, arrays=cs.arrays._replace(prim_geo=flat))
    np.testing.assert_array_equal(render_tile(copy, 0, 0, 8, 6, 0, 4, kernel="packet").sum,
                                  first.sum)
    assert calls == {"covers": 2, "columns": 2}


def test_sin_cos_quarter_against_numpy():
    x = np.linspace(-math.pi / 4, math.pi / 4, 20001).astype(np.float32)
    s, c = np.vectorize(sin_cos_quarter.py_func)(x)
    assert np.abs(s - np.sin(x.astype(np.float64))).max() < 2e-7
    assert np.abs(c - np.cos(x.astype(np.float64))).max() < 5e-7


def test_cosine_direction_is_cosine_distributed():
    """Moments of the cosine-weighted hemisphere (E[z] = 2/3, E[z²] = 1/2, E[x] = E[y] = 0,
    unit length) and chi² tests of cos²θ (uniform on [0, 1) under p ∝ cos θ) and of φ
    (uniform) over 200 000 directions."""
    rng = np.random.default_rng(7)
    u = rng.random((200_000, 2)).astype(np.float32)
    d = np.array([cosine_direction(a, b) for a, b in u], np.float64)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-6)
    assert d[:, 2].min() >= 0.0
    assert abs(d[:, 2].mean() - 2 / 3) < 4 * math.sqrt(1 / 2 - 4 / 9) / math.sqrt(len(d))
    assert abs((d[:, 2] ** 2).mean() - 0.5) < 0.003
    assert abs(d[:, 0].mean()) < 0.005 and abs(d[:, 1].mean()) < 0.005
    for values in (d[:, 2] ** 2, (np.arctan2(d[:, 1], d[:, 0]) + math.pi) / (2 * math.pi)):
        observed = np.histogram(values, bins=50, range=(0, 1))[0]
        assert stats.chisquare(observed).pvalue > 1e-3


def seed_boxes(name: str, max_depth: int, **material) -> dict:
    """The seed paper's boxes (single_scatter) at 32×24, both boxes' material changed by
    ``material``. Name "lamp": the low-density boxes under a light as wide as the room, the
    walls black but the floor: most of the image is light reaching the floor or an event
    through a box, each found by a light sample and by the direction sampled, so the two MIS
    weights must be consistent (the light's density measured from the last scattering vertex,
    not from where the ray last crossed a box: measured from there, the lower half's mean moves
    by 9 standard errors)."""
    lamp = name == "lamp"
    data = json.loads((EXAMPLES / f"seed_paper_boxes_{'low' if lamp else name}_density.json")
                      .read_text())
    data["film"] = {"width": 32, "height": 24}
    data["render"].update(spp=256, seed=5, max_depth=max_depth)
    for m in data["materials"].values():
        if m["type"] == "translucent":
            m.update(material)
    if lamp:
        data["materials"].update(red={"type": "diffuse", "albedo": [0, 0, 0]},
                                 green={"type": "diffuse", "albedo": [0, 0, 0]},
                                 black={"type": "diffuse", "albedo": [0, 0, 0]})
        for o in data["objects"][1:5]:
            o["material"] = o["material"] if o["material"] != "white" else "black"
        light = data["objects"][-1]
        light.update(origin=[-0.95, 0.99, -0.95], edge1=[1.9, 0, 0], edge2=[0, 0, 1.9],
                     emission=[2.0, 1.5, 1.0])
    return data


@pytest.mark.parametrize(("name", "max_depth", "material"), [
    ("low", 8, {}),
    ("high", 2, {}),
    ("high", 1, {}),
    ("low", -1, {"g": 0.6, "surface_fraction": 0.3, "density": 3.0}),
    ("high", -1, {"g": -0.4, "surface_fraction": 0.7}),
    ("lamp", 2, {"g": 0.7, "surface_fraction": 0.1, "density": 0.7}),
])
def test_single_scatter_boxes_agree_with_the_scalar_kernel(name, max_depth, material):
    """The seed paper's boxes (single_scatter: a surface share reflecting as a diffuse surface,
    the rest going in straight, one scattering event inside with a light sample through the
    medium, out straight, attenuated): both kernels estimate the same image, frame and half
    frames within 4.5 standard errors, at the paper's depth limit and at the limits that cut the
    paths at and after the event, with forward and backward phase functions; the path segments
    per sample (crossings and events included) agree within 2 %."""
    cs = compiled(seed_boxes(name, max_depth, **material))
    assert unsupported(cs) is None
    a = render_buffer(cs, 256, kernel="packet")
    b = render_buffer(cs, 256, kernel="scalar")
    assert_same_means(a, b)
    segments = [buf.segments.sum() / buf.count.sum() for buf in (a, b)]
    assert abs(segments[0] / segments[1] - 1.0) < 0.02, segments
    assert not a.dropped.any()


def test_exp32_and_log32_against_numpy():
    """The vector lanes' exp (of x ≤ 0) and log (of a free flight's 1 − u)."""
    exp = numba.njit(lambda x: exp32(x))
    log = numba.njit(lambda x: log32(x))
    x = -np.concatenate([np.linspace(0.0, 87.0, 20001), np.geomspace(1e-8, 1.0, 500)])
    x = x.astype(np.float32)
    got = np.array([exp(v) for v in x], np.float64)
    want = np.exp(x.astype(np.float64))
    assert np.max(np.abs(got - want) / want) < 4e-6
    assert exp(np.float32(0.0)) == 1.0 and exp(np.float32(-1e30)) < 1e-37
    u = np.concatenate([np.geomspace(2.0 ** -24, 1.0, 20001), [0.5, 0.75, 1.0]])
    u = u.astype(np.float32)
    got = np.array([log(v) for v in u], np.float64)
    assert np.max(np.abs(got - np.log(u.astype(np.float64)))) < 2e-6
    assert log(np.float32(1.0)) == 0.0


@numba.njit
def _hg_directions(u, g):
    out = np.empty((u.shape[0], 4), np.float64)
    for i in range(u.shape[0]):
        x, y, z = hg_direction(u[i, 0], u[i, 1], g)
        out[i, 0], out[i, 1], out[i, 2] = x, y, z
        out[i, 3] = hg_pdf32(z, g)
    return out


@pytest.mark.parametrize("g", [0.0, 0.6, -0.4, 0.95])
def test_hg_direction_is_henyey_greenstein_distributed(g):
    """200 000 directions: unit length, E[cos θ] = g (Henyey–Greenstein's mean cosine), a chi²
    test of cos θ against the phase function's cdf (1 − g²)/(2g)·((1 + g² − 2gμ)^−½ − 1/(1 + g))
    (uniform for g = 0) and of φ against uniform; the density integrates to 1 over the
    sphere (the mean of 1/pdf over its samples is 4π)."""
    rng = np.random.default_rng(3)
    u = rng.random((200_000, 2)).astype(np.float32)
    d = _hg_directions(u, np.float32(g))
    np.testing.assert_allclose(np.linalg.norm(d[:, :3], axis=1), 1.0, atol=2e-6)
    mu = d[:, 2]
    sd = math.sqrt(max(mu.var(), 1e-12) / len(mu))
    assert abs(mu.mean() - g) < 5 * sd + 1e-6
    if g == 0.0:
        cdf = (mu + 1.0) / 2.0
    else:
        cdf = (1 - g * g) / (2 * g) * (1 / np.sqrt(1 + g * g - 2 * g * mu) - 1 / (1 + g))
    phi = (np.arctan2(d[:, 1], d[:, 0]) + math.pi) / (2 * math.pi)
    for values in (cdf, phi):
        observed = np.histogram(values, bins=50, range=(0, 1))[0]
        assert stats.chisquare(observed).pvalue > 1e-3
    if abs(g) < 0.9:  # (at 0.95 the backward directions' 1/pdf is too heavy a tail)
        assert abs(np.mean(1.0 / d[:, 3]) / (4 * math.pi) - 1.0) < 0.02


def test_an_event_samples_the_phase_function_and_weighs_its_light_sample():
    """``_scatter`` on 16 lanes at a medium's event (g 0.6, albedo 1, a square light above):
    the new direction's density (PDF_B, the MIS weight of an emitter found next) is
    Henyey–Greenstein's at the angle turned, the event's point is FLIGHT along the ray, and its
    light sample carries Le · phase · w / pdf_l with w the power heuristic of pdf_l (solid angle)
    against the phase function, as ``renderer.integrators.direct.medium_direct`` computes it."""
    from renderer import packet as pk
    from renderer.materials.phase import hg_pdf

    lanes, g = pk.LANES, 0.6
    P = np.zeros(pk.FLOAT_ROWS * lanes, np.float32)
    Q = np.zeros(pk.INT_ROWS * lanes, np.int32)
    rng = np.random.default_rng(9)
    d = rng.normal(size=(lanes, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    o = rng.uniform(-0.3, 0.3, (lanes, 3))

    def put(row, values):
        P[row:row + lanes] = values

    for k, row in enumerate((pk.OX, pk.OY, pk.OZ)):
        put(row, o[:, k])
    for k, row in enumerate((pk.DX, pk.DY, pk.DZ)):
        put(row, d[:, k])
    for row in (pk.TR, pk.TG, pk.TB, pk.MAR, pk.MAG, pk.MAB):
        put(row, 1.0)
    put(pk.FLIGHT, 0.1)
    put(pk.MG, g)
    # the light: a 0.5 × 0.5 square at y = 1 facing down, emission (4, 3, 2), pmf 1
    for row, value in ((pk.QOX, -0.25), (pk.QOY, 1.0), (pk.QOZ, -0.25), (pk.QAX, 0.5),
                       (pk.QBZ, 0.5), (pk.QNY, -1.0), (pk.Q_PA, 4.0), (pk.QER, 4.0),
                       (pk.QEG, 3.0), (pk.QEB, 2.0)):
        put(row, value)
    Q[pk.EVENT:pk.EVENT + lanes] = 1
    Q[pk.IN_MED:pk.IN_MED + lanes] = 1
    pk._scatter(P, Q, np.arange(lanes, dtype=np.uint32) * np.uint32(7919), np.float32(1e-4),
                np.int32(-1), False)

    def get(row):
        return P[row:row + lanes].astype(np.float64)

    p = o + 0.1 * d
    np.testing.assert_allclose(np.stack([get(pk.OX), get(pk.OY), get(pk.OZ)], 1), p, atol=1e-6)
    new = np.stack([get(pk.DX), get(pk.DY), get(pk.DZ)], 1)
    np.testing.assert_allclose(np.linalg.norm(new, axis=1), 1.0, atol=1e-5)
    turned = np.einsum("ij,ij->i", d, new)
    np.testing.assert_allclose(get(pk.PDF_B), [hg_pdf(c, g) for c in turned], rtol=2e-4)
    assert (Q[pk.DEPTH:pk.DEPTH + lanes] == 1).all() and (Q[pk.DONE:pk.DONE + lanes] == 1).all()
    # the light sample: direction to its point, pdf in solid angle, the power heuristic
    w = np.stack([get(pk.SX), get(pk.SY), get(pk.SZ)], 1)
    dist = get(pk.S_DIST) + 1e-4
    point = p + w * dist[:, None]
    np.testing.assert_allclose(point[:, 1], 1.0, atol=1e-5)
    assert (np.abs(point[:, [0, 2]]) <= 0.25 + 1e-5).all()
    cos_l = w[:, 1]
    pdf_l = 4.0 * dist ** 2 / cos_l
    ph = np.array([hg_pdf(c, g) for c in np.einsum("ij,ij->i", d, w)])
    expected = ph * pdf_l / (pdf_l ** 2 + ph ** 2)
    assert (Q[pk.OCCLUDED:pk.OCCLUDED + lanes] == 0).all()
    for row, le in ((pk.CR, 4.0), (pk.CG, 3.0), (pk.CB, 2.0)):
        np.testing.assert_allclose(get(row), le * expected, rtol=2e-4)


@pytest.mark.parametrize(("change", "reason"), [
    (lambda d: d["objects"].append({"type": "sphere", "center": [0, -0.7, 0], "radius": 0.2,
                                    "material": "white"}), "spheres"),
    (lambda d: d["materials"].update(white={"type": "phong", "diffuse": [0.5] * 3,
                                            "specular": [0.2] * 3, "exponent": 20}),
     "materials other than diffuse"),
    (lambda d: d.update(lights=[{"type": "point", "position": [0, 0.5, 0],
                                 "intensity": [1, 1, 1]}]), "lights other than"),
    (lambda d: d.update(background=[0.1, 0.1, 0.1]), "lights other than"),
    (lambda d: d["materials"].update(white={"type": "translucent", "method": "single_scatter",
                                            "albedo": [0.8] * 3, "density": [1.0, 2.0, 3.0]}),
     "chromatic"),
    (lambda d: d["objects"].extend([{"type": "quad", "origin": [-1, -1 + k / 100, 0.5],
                                     "edge1": [0.1, 0, 0], "edge2": [0, 0, 0.1],
                                     "material": "white"} for k in range(10)]), "primitives"),
])
def test_what_it_leaves_to_the_scalar_kernel(change, reason):
    data = cornell(8, 6, spp=2)
    change(data)
    cs = compiled(data)
    why = unsupported(cs)
    assert why is not None and reason in why
    # render_tile falls back to the scalar kernel: the same sums bit for bit
    a = render_tile(cs, 0, 0, 8, 6, 0, 2, kernel="packet")
    b = render_tile(cs, 0, 0, 8, 6, 0, 2, kernel="scalar")
    np.testing.assert_array_equal(a.sum, b.sum)


def moved(data: dict, offset: float) -> dict:
    """The scene and camera moved by ``offset`` along x."""
    data = json.loads(json.dumps(data))
    data["camera"]["position"][0] += offset
    data["camera"]["look_at"][0] += offset
    for o in data["objects"]:
        if o["type"] == "quad":
            o["origin"][0] += offset
        else:
            o["translate"][0] += offset
    return data


def test_far_from_the_origin_float32_is_not_enough():
    """Moved 30 times its size from the origin, the Cornell box is left to the scalar kernel
    (float64): the packet kernel's offset would be 1e-4 of the coordinate. Moved 5 times its size
    (offset 2e-3 of the room) it stays the packet kernel's and renders the same frame mean within
    noise as at the origin: no surface finds itself, no light leaks through the corners."""
    base = cornell(24, 18, spp=64, seed=2)
    assert "from the origin" in unsupported(compiled(moved(base, 100.0)))
    near = compiled(moved(base, 16.0))
    assert unsupported(near) is None
    here = render(base, kernel="packet").astype(np.float64)
    there = render_buffer(near, kernel="packet")
    img = there.mean().astype(np.float64)
    assert not there.dropped.any()
    np.testing.assert_allclose(img.mean(axis=(0, 1)), here.mean(axis=(0, 1)), rtol=0.04)
