"""bench.auto_target: the loop with the bias of ``auto``'s model ignored and aimed at, on the same
scene, seeds and reference (``run``)."""

from __future__ import annotations

import numpy as np
import pytest

import bench.auto_target as at
import renderer.render
from renderer.film.buffer import SampleBuffer


def test_run_renders_each_seed_with_the_bias_ignored_and_aimed_at(monkeypatch):
    """Each seed (7, 8, …) is rendered twice from the one compiled scene: once with
    ``expected_bias`` 0 (the target alone) and once with the compile's ``frame_bias``; the row's
    errors are the means over the seeds against the view's one reference (rendered without the
    target), over the frame and over the object's pixels."""
    seen: list[tuple[int, float, float | None]] = []

    def render_buffer(cs, spp=None):
        seen.append((cs.seed, cs.expected_bias, cs.target_error))
        buf = SampleBuffer.empty(0, 0, cs.width, cs.height)
        # an image whose error against a reference of ones is (seed − 6)² / 100 · (1 + 1000 bias)
        buf.count[:] = 10
        value = 1.0 + 0.1 * (cs.seed - 6) * np.sqrt(1.0 + 1e3 * cs.expected_bias)
        buf.sum[:] = 10 * value
        return buf

    refs = []

    def reference(name, scene, material, spp):
        refs.append((name, "target_error" in scene["render"], spp))
        return np.ones((48, 64, 3)), "ones"

    monkeypatch.setattr(renderer.render, "render_buffer", render_buffer)
    monkeypatch.setattr(at, "reference", reference)
    monkeypatch.setattr(at, "object_mask", lambda scene, material: np.eye(48, 64, dtype=bool))
    row = at.run("close 1.3", 0.01, seeds=2, ref_spp=64)
    assert refs == [("dense_wax_close_1.3", False, 64)]
    bias = row["frame_bias"]
    assert row["auto_method"] == "opaque" and 0.005 < bias < 0.00847
    assert row["share_covered"] == pytest.approx(48 / (48 * 64))
    # (the kernels' load, then two seeds with the bias ignored, two with it aimed at)
    assert seen[1:] == [(7, 0.0, 0.01), (8, 0.0, 0.01), (7, bias, 0.01), (8, bias, 0.01)]
    rel = 1.0 / 1.01  # (v − 1)² / (1 + 0.01) against a reference of ones
    ignored = np.mean([0.01 * k * k for k in (1, 2)]) * rel
    assert row["ignored_err"] == pytest.approx(ignored, rel=1e-6)
    assert row["ignored_err_over_target"] == pytest.approx(ignored / 0.01, rel=1e-6)
    assert row["aimed_err"] == pytest.approx(ignored * (1.0 + 1e3 * bias), rel=1e-6)
    # the standard error of the mean err/target over the seeds (errors 0.01 and 0.04 × rel)
    assert row["ignored_se"] == pytest.approx(0.015 * rel / 0.01, rel=1e-6)
    assert row["object_err_aimed"] == pytest.approx(row["aimed_err"], rel=1e-6)
    assert row["ignored_spp"] == row["aimed_spp"] == 10.0
    # albedo 0.8: its own reference, and the opaque surface's smaller error at that albedo
    row = at.run("close 1.3", 0.01, seeds=1, ref_spp=64, albedo=0.8)
    assert refs[-1] == ("dense_wax_close_1.3_albedo_0.8", False, 64)
    assert row["albedo"] == 0.8 and row["auto_method"] == "opaque"
    assert row["frame_bias"] == pytest.approx(bias * 0.00189 / 0.00847, rel=1e-9)
