"""bench.denoise: uniform sampling's samples and error at a denoised render's time, its edge
mask, and its rows written, read back, tabled and charted (a fake renderer with known times and
errors: no OIDN needed)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import bench.denoise as dn


def test_spp_at_is_log_log_linear_inside_and_proportional_to_time_beyond():
    ts, spp = np.array([1.0, 4.0]), np.array([4.0, 64.0])
    assert dn.spp_at(2.0, ts, spp) == pytest.approx(16.0)  # √(4·64): halfway in log
    assert dn.spp_at(0.5, ts, spp) == pytest.approx(2.0)
    assert dn.spp_at(8.0, ts, spp) == pytest.approx(128.0)


def test_the_edge_mask_is_the_share_of_pixels_where_the_luminance_steps():
    ref = np.zeros((8, 64, 3))
    ref[:, 32:] = 1.0
    mask = dn.edge_mask(ref, share=2 / 64)
    assert mask.shape == (8, 64)
    assert mask[:, 31].all() and mask[:, 32].all()  # the step's two columns (central differences)
    assert mask.sum() == 16


C = 0.5  # the fake renders' relMSE at 1 spp (off the edges); C / n at n


def _fake(ref: np.ndarray, calls: list):
    """A renderer whose image at n spp has relMSE exactly C / n against ``ref`` off its edges
    (every pixel off by the same relative amount) and 4 C / n on them, in n ms, twice that when
    denoised; a denoised image is as good as 4× the samples."""
    edges = dn.edge_mask(ref)

    def runner(data: dict, repeat: int, denoised: bool):
        n = data["render"]["spp"]
        calls.append((n, repeat, denoised))
        effective = 4 * n if denoised else n
        img = ref + np.sqrt(C / effective * (ref**2 + 0.01)) * (1.0 + edges[..., None])
        return (2e-3 if denoised else 1e-3) * n, img
    return runner


def test_a_denoised_render_is_compared_with_uniform_sampling_at_its_time():
    ref = np.random.default_rng(1).uniform(0.1, 2.0, (6, 8, 3))
    calls: list = []
    rows = dn.measure("fake", {"render": {}}, None, ref, [4, 16], 3, _fake(ref, calls))
    assert calls[0] == (1, 1, True)  # the warm-up
    assert calls[1:] == [(n, 3, False) for n in dn.UNIFORM_SPP] + [(4, 3, True), (16, 3, True)]
    uniform = [r for r in rows if r["kind"] == "uniform"]
    assert [r["spp"] for r in uniform] == list(dn.UNIFORM_SPP)
    share = dn.edge_mask(ref).mean()
    for r in uniform:
        assert r["rel_mse"] == pytest.approx(C / r["spp"] * (1 + 3 * share))
        assert r["edges"] == pytest.approx(4 * C / r["spp"])
        assert math.isnan(r["uniform_rel_mse"])
    denoised = [r for r in rows if r["kind"] == "denoised"]
    for r, n in zip(denoised, (4, 16), strict=True):
        assert r["seconds"] == pytest.approx(2e-3 * n)
        assert r["rel_mse"] == pytest.approx(C / (4 * n) * (1 + 3 * share))
        # the time of 2n uniform samples, whose errors are twice the denoised one's
        assert r["uniform_spp"] == pytest.approx(2 * n)
        assert r["uniform_rel_mse"] == pytest.approx(C / (2 * n) * (1 + 3 * share))
        assert r["uniform_edges"] == pytest.approx(4 * C / (2 * n))


def test_rows_survive_the_csv_and_make_the_tables(tmp_path, capsys):
    ref = np.full((6, 8, 3), 0.5)
    rows = dn.measure("fake", {"render": {}}, None, ref, [4, 16], 1, _fake(ref, []))
    path = tmp_path / "d" / "rows.csv"
    dn.write_csv(rows, path)
    back = dn.read_csv(path)
    assert len(back) == len(rows)
    for a, b in zip(rows, back, strict=True):
        assert a.keys() == b.keys()
        for k in a:
            assert (a[k] == b[k] or (isinstance(a[k], float) and math.isnan(a[k])
                                     and math.isnan(b[k]))), k
    lines = dn.table(back).splitlines()
    assert len(lines) == 2 + 2  # the header, its rule, the two denoised rows
    assert lines[2].startswith("| fake | 4 | 0.008 |")
    assert lines[2].endswith("| 2 | 2 |")  # the gains: C/8 over C/16
    assert dn.gains(back).splitlines() == ["| scene | 4 spp | 16 spp |", "|---|---:|---:|",
                                           "| fake | 2 · 2 | 2 · 2 |"]
    assert dn.main(["--from-csv", str(path)]) == 0
    out = capsys.readouterr().out
    assert "| fake | 16 |" in out and "| fake | 2 · 2 | 2 · 2 |" in out


def test_the_chart_is_drawn(tmp_path):
    pytest.importorskip("matplotlib")  # (the bench and test extras)
    ref = np.full((6, 8, 3), 0.5)
    rows = dn.measure("fake", {"render": {}}, None, ref, [4, 16], 1, _fake(ref, []))
    png = tmp_path / "chart.png"
    dn.chart(rows, png)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
