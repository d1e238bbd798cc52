"""bench.target_error --spread: the target loop run with many seeds, untimed, its mean
error/target (the expected relMSE over the target) and single runs' spread (``spread``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import bench.target_error as te
import renderer.render
from renderer.film.buffer import SampleBuffer


def test_spread_gives_the_mean_error_over_seeds_and_single_runs_spread(monkeypatch, capsys):
    """A render whose relMSE is its image's value: seed s (7, 8, …) of a run with a target
    gives 0.01 · (s − 6)² at 10 + s samples a pixel, so ten seeds give error/target 0.1, 0.4,
    0.9, …, 10 at target 0.1 (mean 3.85, median 3.05), of which 0.9 alone lies in [0.5, 1.1];
    each seed is rendered once, with the target and the cap the bench uses."""
    scene = json.loads((te.ROOT / "examples" / "cornell_box.json").read_text())
    scene["film"] = {"width": 4, "height": 3}
    seen: list[tuple[int, float | None, int]] = []

    def render_buffer(cs, even=False):
        seen.append((cs.seed, cs.target_error, cs.spp))
        buf = SampleBuffer.empty(0, 0, cs.width, cs.height)
        buf.count[:] = 10 + cs.seed
        buf.sum[:] = buf.count[..., None] * 0.01 * (cs.seed - 6) ** 2
        return buf

    monkeypatch.setattr(renderer.render, "render_buffer", render_buffer)
    monkeypatch.setattr(te, "rel_mse", lambda image, ref: float(image.mean()))
    monkeypatch.setattr(te, "scene_reference", lambda *a, **k: np.ones((3, 4, 3)))
    [row] = te.spread(["tiny"], {"tiny": (scene, None)}, [0.1], seeds=10)
    assert seen == [(7 + k, 0.1, te.CAP) for k in range(10)]
    ratios = 0.1 * np.arange(1, 11) ** 2
    assert row["seeds"] == 10 and row["mean_spp"] == pytest.approx(10 + 11.5)
    assert row["ratio"] == pytest.approx(3.85)
    assert row["ratio_se"] == pytest.approx(ratios.std(ddof=1) / np.sqrt(10))
    assert row["ratio_median"] == pytest.approx(3.05)
    assert row["ratio_p10"] == pytest.approx(np.percentile(ratios, 10))
    assert row["ratio_p90"] == pytest.approx(np.percentile(ratios, 90))
    assert (row["ratio_min"], row["ratio_max"]) == pytest.approx((0.1, 10.0))
    assert row["in_range"] == pytest.approx(0.1)
    out = capsys.readouterr().out
    assert "0 of 1 in [0.5, 1.1]" in out and "10% on average" in out


def test_spread_is_the_default_of_32_seeds_from_the_command_line(monkeypatch, tmp_path):
    calls = []
    monkeypatch.setattr(te, "spread", lambda names, scenes, targets, seeds, ref_spp:
                        calls.append((names, targets, seeds, ref_spp)) or
                        [{"scene": names[0], "target": targets[0], "ratio": 0.8}])
    out = tmp_path / "spread.csv"
    assert te.main(["--spread", "--scenes", "cornell_box", "--targets", "0.1",
                    "--out", str(out)]) == 0
    assert te.main(["--spread", "--scenes", "cornell_box", "--targets", "0.1",
                    "--seeds", "5"]) == 0
    assert calls == [(["cornell_box"], [0.1], 32, te.REF_SPP),
                     (["cornell_box"], [0.1], 5, te.REF_SPP)]
    assert out.read_text().splitlines() == ["scene,target,ratio", "cornell_box,0.1,0.8"]
