"""The ``lucent`` command line, as a user runs it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from renderer.film.image_io import read_image
from renderer.render import render
from renderer.scene import load_scene_file
from renderer.scene.compile import compile_scene
from services.cli import main

ROOT = Path(__file__).resolve().parents[2]


def small_scene(tmp_path: Path, **changes) -> Path:
    data = json.loads((ROOT / "examples" / "cornell_box.json").read_text())
    data["film"] = {"width": 24, "height": 18}
    data["render"]["spp"] = 4
    data.update(changes)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(data))
    return path


def test_render_writes_every_format(tmp_path, capsys):
    scene = small_scene(tmp_path)
    images = {}
    for ext in ("npy", "exr", "pfm", "png"):
        out = tmp_path / f"out.{ext}"
        assert main(["render", str(scene), "-o", str(out), "--spp", "2", "-q"]) == 0
        images[ext] = read_image(out)
    assert images["npy"].shape == (18, 24, 3)
    np.testing.assert_array_equal(images["npy"], images["exr"])
    np.testing.assert_array_equal(images["npy"], images["pfm"])
    assert images["npy"].max() > 0.05  # the box is lit
    assert "samples/s" in capsys.readouterr().err


def test_seed_option_changes_the_image(tmp_path):
    scene = small_scene(tmp_path)
    outs = []
    for seed in ("1", "2", "1"):
        out = tmp_path / f"s{len(outs)}.npy"
        assert main(["render", str(scene), "-o", str(out), "--seed", seed, "-q"]) == 0
        outs.append(np.load(out))
    np.testing.assert_array_equal(outs[0], outs[2])
    assert not np.array_equal(outs[0], outs[1])


def test_sampler_option(tmp_path):
    """--sampler sobol renders other samples of the same image (unbiased: close means)."""
    scene = small_scene(tmp_path)
    outs = {}
    for sampler in ("independent", "sobol"):
        out = tmp_path / f"{sampler}.npy"
        assert main(["render", str(scene), "-o", str(out), "--sampler", sampler, "--spp", "64",
                     "-q"]) == 0
        outs[sampler] = np.load(out)
    assert not np.array_equal(outs["independent"], outs["sobol"])
    np.testing.assert_allclose(outs["sobol"].mean(), outs["independent"].mean(), rtol=0.05)


def test_validate_reports_fields_and_fails(tmp_path, capsys):
    data = json.loads(small_scene(tmp_path).read_text())
    data["objects"][0]["material"] = "nope"
    data["film"]["width"] = 0
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(data))
    assert main(["validate", str(bad)]) == 1
    err = capsys.readouterr().err
    assert "film.width" in err
    assert main(["validate", str(small_scene(tmp_path))]) == 0
    assert "ok" in capsys.readouterr().out


def test_render_refuses_unknown_image_type(tmp_path, capsys):
    assert main(["render", str(small_scene(tmp_path)), "-o", str(tmp_path / "x.jpg")]) == 2
    assert ".exr" in capsys.readouterr().err


def test_render_uses_the_packet_kernel_where_it_covers_the_scene(tmp_path, capsys):
    """The default kernel is the packet kernel: on a scene it covers the image is its own
    (``render_tile(kernel="packet")``), not the scalar kernel's (``--kernel scalar``), and
    nothing is said; on a scene it does not cover the scalar kernel renders it and says why."""
    scene = small_scene(tmp_path)
    assert main(["render", str(scene), "-o", str(tmp_path / "a.npy"), "-q"]) == 0
    assert "packet kernel" not in capsys.readouterr().err
    assert main(["render", str(scene), "-o", str(tmp_path / "b.npy"), "-q", "--kernel",
                 "scalar"]) == 0
    assert "packet kernel" not in capsys.readouterr().err
    compiled = compile_scene(load_scene_file(scene))
    np.testing.assert_array_equal(np.load(tmp_path / "a.npy"), render(compiled, kernel="packet"))
    np.testing.assert_array_equal(np.load(tmp_path / "b.npy"), render(compiled, kernel="scalar"))
    assert not np.array_equal(np.load(tmp_path / "a.npy"), np.load(tmp_path / "b.npy"))
    data = json.loads(scene.read_text())
    data["objects"].append({"type": "sphere", "center": [0, -0.6, 0], "radius": 0.3,
                            "material": "white"})
    spheres = tmp_path / "spheres.json"
    spheres.write_text(json.dumps(data))
    assert main(["render", str(spheres), "-o", str(tmp_path / "c.npy"), "-q"]) == 0
    err = capsys.readouterr().err
    assert "the packet kernel does not cover spheres" in err
    assert "the scalar kernel renders it" in err
    np.testing.assert_array_equal(np.load(tmp_path / "c.npy"),
                                  render(compile_scene(load_scene_file(spheres)), kernel="scalar"))


def test_render_reports_what_auto_chose(tmp_path, capsys):
    data = json.loads(small_scene(tmp_path).read_text())
    data["materials"]["wax"] = {"type": "translucent", "method": "auto", "ior": 1.3,
                                "albedo": [0.9, 0.8, 0.7], "density": 5.0}
    data["objects"].append({"type": "sphere", "center": [0, -0.6, 0], "radius": 0.4,
                            "material": "wax"})
    path = tmp_path / "wax.json"
    path.write_text(json.dumps(data))
    assert main(["render", str(path), "-o", str(tmp_path / "x.npy"), "-q"]) == 0
    line = next(x for x in capsys.readouterr().err.splitlines() if x.startswith("auto chose"))
    assert line.startswith("auto chose volumetric for 'wax': optical radius 2")
    assert line.endswith("; expected bias none (unbiased: the error is the samples' noise alone)")


def test_render_with_a_target_says_the_plan_and_what_it_reached(tmp_path, capsys):
    """render.target_error: the CLI tells the pilot's planned samples and the error they aim at
    (AIM × target), then the expected relMSE reached (at most the target) and the samples a
    pixel took."""
    data = json.loads(small_scene(tmp_path).read_text())
    data["render"].update(spp=2048, target_error=0.05)
    path = tmp_path / "target.json"
    path.write_text(json.dumps(data))
    assert main(["render", str(path), "-o", str(tmp_path / "x.npy"), "-q"]) == 0
    err = capsys.readouterr().err
    assert "target relMSE 0.05: after the pilot the allocation plans" in err
    assert "to reach an expected relMSE of 0.04 (0.8 × target)" in err
    line = next(x for x in err.splitlines() if x.startswith("reached: expected relMSE"))
    reached = float(line.split()[3])
    assert 0 < reached <= 0.05


def test_render_with_a_loose_target_says_the_first_look_reached_it(tmp_path, capsys):
    """A target the pilot's first look reaches: the CLI says that its samples already reach the
    aim (not an allocation's plan), and the frame has FIRST_LOOK samples a pixel."""
    from renderer.film.adaptive import FIRST_LOOK

    data = json.loads(small_scene(tmp_path).read_text())
    # (64×48: on 24×18 the few pixels at the light carry the estimate, too few for the bound)
    data["film"] = {"width": 64, "height": 48}
    data["render"].update(spp=2048, target_error=0.5)
    path = tmp_path / "target.json"
    path.write_text(json.dumps(data))
    out = tmp_path / "x.npy"
    assert main(["render", str(path), "-o", str(out), "-q"]) == 0
    err = capsys.readouterr().err
    assert (f"target relMSE 0.5: the pilot's first {FIRST_LOOK} spp a pixel already reach an "
            "expected relMSE of 0.4 (0.8 × target)") in err
    assert "after the pilot the allocation plans" not in err
    line = next(x for x in err.splitlines() if x.startswith("reached: expected relMSE"))
    assert f"{FIRST_LOOK} spp a pixel on average ({FIRST_LOOK}–{FIRST_LOOK})" in line, line


def test_render_with_a_target_counts_the_bias_of_the_model_auto_chose(tmp_path, capsys):
    """A close-up of dense wax that auto renders as the opaque surface, with a target: the plan
    aims the samples' noise at the target less the bias the model may add over the frame, and
    the line of what was reached gives the noise and the bias, their sum within the target."""
    from renderer.materials.auto import frame_bias

    data = json.loads((ROOT / "examples" / "translucent_sphere.json").read_text())
    data["film"] = {"width": 32, "height": 24}
    data["camera"].update(position=[0.0, -0.5, 1.3], look_at=[0.0, -0.5, 0.0])
    data["materials"]["wax"].update(method="auto", albedo=[0.99] * 3, g=0.5, density=3000.0)
    data["render"].update(spp=4096, target_error=0.01)
    path = _write(tmp_path / "dense.json", data)
    bias = frame_bias(load_scene_file(path))
    assert main(["render", str(path), "-o", str(tmp_path / "x.npy"), "-q"]) == 0
    err = capsys.readouterr().err
    assert "auto chose opaque for 'wax'" in err
    assert (f"to reach an expected relMSE of {0.8 * (0.01 - bias):.3g} from the samples' noise "
            f"(0.8 × {0.01 - bias:.3g}: the target less the bias auto's models may add, "
            f"{bias:.3g})") in err
    line = next(x for x in err.splitlines() if x.startswith("reached: expected relMSE"))
    assert "(target 0.01; the samples' noise " in line
    assert f" and the bias of auto's models, at most {bias:.3g})" in line
    reached, noise = float(line.split()[3]), float(line.split()[9])
    assert noise + bias == pytest.approx(reached, rel=2e-3)
    assert noise <= 0.8 * (0.01 - bias) * 1.05 and reached <= 0.01


def test_target_error_option_sets_and_drops_the_scenes_target(tmp_path, capsys):
    """--target-error T renders a scene without a target to T, --spp the most a pixel takes;
    --target-error none renders a scene with a target at its spp everywhere, the same frame as
    without the target."""
    scene = small_scene(tmp_path)
    out = tmp_path / "t.npy"
    assert main(["render", str(scene), "-o", str(out), "--spp", "2048",
                 "--target-error", "0.05", "-q"]) == 0
    err = capsys.readouterr().err
    assert "24x18, target relMSE 0.05, at most 2048 spp a pixel," in err
    assert "target relMSE 0.05: after the pilot the allocation plans" in err
    line = next(x for x in err.splitlines() if x.startswith("reached: expected relMSE"))
    assert 0 < float(line.split()[3]) <= 0.05
    assert 8 <= float(line.split()[6]) < 2048  # (mean spp: past the pilot, far below the cap)
    assert "more reaches the target" not in line
    # A cap too low for the target: the plan says what the cap reaches (not the aim), and the
    # line of what was reached that the pixels stopped at it
    assert main(["render", str(scene), "-o", str(out), "--spp", "12",
                 "--target-error", "0.0001", "-q"]) == 0
    err = capsys.readouterr().err
    said = next(x for x in err.splitlines() if x.startswith("target relMSE 0.0001:"))
    assert said.startswith("target relMSE 0.0001: after the pilot the allocation plans 12 spp "
                           "a pixel on average, capped at 12 (--spp or render.spp), for an "
                           "expected relMSE of "), said
    assert said.endswith(" by the pilot's estimate: above the target, which more samples a "
                         "pixel would reach"), said
    line = next(x for x in err.splitlines() if x.startswith("reached:"))
    assert line.endswith("; pixels stopped at the most a pixel takes, 12 spp (--spp or "
                         "render.spp): more reaches the target"), line
    # (what the plan expected of 12 samples a pixel, from the pilot's 8: what they reached)
    planned = float(said.split("expected relMSE of ")[1].split()[0])
    reached = float(line.split()[3])
    assert 0.8 * reached <= planned <= 1.25 * reached, (planned, reached)

    data = json.loads(scene.read_text())
    data["render"].update(spp=16, target_error=0.05)
    targeted = tmp_path / "targeted.json"
    targeted.write_text(json.dumps(data))
    assert main(["render", str(targeted), "-o", str(out), "--target-error", "none", "-q"]) == 0
    err = capsys.readouterr().err
    assert "24x18, 16 spp," in err and "reached" not in err and "target relMSE" not in err
    data["render"]["target_error"] = None
    want = render(compile_scene(load_scene_file(_write(tmp_path / "plain.json", data))))
    np.testing.assert_array_equal(np.load(out), want)


def test_the_progress_bar_of_a_target_render_counts_its_samples_not_the_caps(tmp_path, capsys):
    """With a target the bar's total is the pilot's plan, raised where a round plans past it,
    and the samples rendered once it ends: it ends full, not at the share of the spp cap
    (2048 a pixel here) that the loop took."""
    import re

    from tqdm import tqdm

    from renderer.render import render_buffer

    scene = small_scene(tmp_path)
    assert main(["render", str(scene), "-o", str(tmp_path / "x.npy"), "--spp", "2048",
                 "--target-error", "0.01"]) == 0
    err = capsys.readouterr().err
    bars = [x for x in re.split(r"[\r\n]", err) if "samples/s]" in x]
    assert bars[-1].lstrip().startswith("100%|"), bars[-1]
    # (the same render's samples: the loop's counts are a function of the scene)
    data = json.loads(scene.read_text())
    data["render"].update(spp=2048, target_error=0.01)
    counts = render_buffer(compile_scene(load_scene_file(_write(tmp_path / "t.json", data)))).count
    done, total = re.search(r"\| *(\S+)/(\S+) \[", bars[-1]).groups()
    assert done == total == tqdm.format_sizeof(int(counts.sum())), bars[-1]
    assert counts.mean() > 8  # (rounds after the pilot)
    # (never the cap's 24 x 18 x 2048 samples as the total)
    assert all(f"/{tqdm.format_sizeof(24 * 18 * 2048)} " not in bar for bar in bars), bars


@pytest.mark.parametrize("value", ["0", "-0.01", "inf", "nan", "abc"])
def test_target_error_option_refuses_what_is_not_a_relmse(tmp_path, capsys, value):
    with pytest.raises(SystemExit) as exit_:
        main(["render", str(small_scene(tmp_path)), "-o", str(tmp_path / "x.npy"),
              "--target-error", value])
    assert exit_.value.code == 2
    assert "argument --target-error:" in capsys.readouterr().err


def test_submit_target_error_option_sets_the_sent_scenes_target(tmp_path, monkeypatch, capsys):
    """lucent submit --target-error: the scene the farm is sent has render.target_error T (none:
    null), its other render fields as the file has them; without the option, the file's."""
    import services.client

    sent: list[dict] = []

    class Farm:
        def __init__(self, server, token=None):
            pass

        def submit(self, scene, **options):
            sent.append(scene)
            return {"id": f"job{len(sent)}", "tiles": 1, "tasks_total": 1}

    monkeypatch.setattr(services.client, "Client", Farm)
    data = json.loads(small_scene(tmp_path).read_text())
    data["render"].update(spp=64, target_error=0.05)
    scene = str(_write(tmp_path / "targeted.json", data))
    for flag, want in ((["--target-error", "0.02"], 0.02), (["--target-error", "none"], None),
                       ([], 0.05)):
        assert main(["submit", scene, "--server", "http://farm"] + flag) == 0
        assert sent[-1]["render"] == {**data["render"], "target_error": want}
    assert capsys.readouterr().out.split() == ["job1", "job2", "job3"]


@pytest.mark.parametrize("expected, short, bias", [(0.016, False, 0.0), (0.03, True, 0.0),
                                                   (0.016, False, 0.006)])
def test_submit_says_when_a_job_stopped_at_its_spp_short_of_its_target(
        tmp_path, monkeypatch, capsys, expected, short, bias):
    """lucent submit --wait: a done job's estimate is given with its target, and where it is
    above the target (the farm stops a frame below it), that render.spp may be what stopped
    it; where auto's models may add a bias, the samples' noise and that bias."""
    import services.client

    class Farm:
        def __init__(self, server, token=None):
            pass

        def submit(self, scene, **options):
            return {"id": "job1", "tiles": 1, "tasks_total": 1}

        def wait(self, job_id, progress=True):
            return {"id": job_id, "status": "done", "dropped_samples": 0, "frames": 1,
                    "spp": 64, "target_error": 0.02, "expected_error": expected,
                    "expected_bias": bias}

    monkeypatch.setattr(services.client, "Client", Farm)
    assert main(["submit", str(small_scene(tmp_path)), "--server", "http://farm", "--wait",
                 "-q"]) == 0
    line = next(x for x in capsys.readouterr().err.splitlines() if x.startswith("expected"))
    parts = (f"; the samples' noise {expected - bias:.3g} and the bias of auto's models, at most "
             f"{bias:.3g}" if bias else "")
    assert line.startswith(f"expected relMSE {expected:g} (target 0.02{parts})"), line
    assert line.endswith("; above the target: a pixel takes at most render.spp, 64 samples, "
                         "and more may reach it") is short


def _write(path: Path, data: dict) -> Path:
    path.write_text(json.dumps(data))
    return path


def test_render_without_a_target_says_its_expected_error(tmp_path, capsys):
    """Every render with 2 samples a pixel or more reports the frame's expected relMSE estimated
    from its samples (``stopping_error``, what a target would stop on); one of 1 sample a pixel
    knows none and says nothing."""
    from renderer.film.adaptive import stopping_error
    from renderer.render import render_buffer

    scene = small_scene(tmp_path)
    assert main(["render", str(scene), "-o", str(tmp_path / "x.npy"), "--spp", "16", "-q"]) == 0
    line = next(x for x in capsys.readouterr().err.splitlines()
                if x.startswith("expected relMSE"))
    assert line.endswith("(estimated from the samples' variance)")
    want = stopping_error(render_buffer(compile_scene(load_scene_file(scene)), 16))
    assert float(line.split()[2]) == float(f"{want:.3g}") and want > 0
    assert main(["render", str(scene), "-o", str(tmp_path / "y.npy"), "--spp", "1", "-q"]) == 0
    assert "relMSE" not in capsys.readouterr().err


def test_console_script_runs_in_a_fresh_process(tmp_path):
    """The installed entry point, end to end, with a mesh read from a file next to the scene."""
    (tmp_path / "tri.obj").write_text("v -0.5 -0.5 0\nv 0.5 -0.5 0\nv 0 0.5 0\nf 1 2 3\n")
    data = json.loads(small_scene(tmp_path).read_text())
    data["objects"].append({"type": "mesh", "path": "tri.obj", "material": "white"})
    scene = tmp_path / "mesh.json"
    scene.write_text(json.dumps(data))
    out = tmp_path / "mesh.png"
    lucent = Path(sys.executable).with_name("lucent")
    cmd = [str(lucent)] if lucent.exists() else [sys.executable, "-m", "services.cli"]
    proc = subprocess.run([*cmd, "render", str(scene), "-o", str(out), "--spp", "2"],
                          capture_output=True, text=True, timeout=300, env=dict(os.environ))
    assert proc.returncode == 0, proc.stderr
    assert out.stat().st_size > 0
    assert "wrote" in proc.stderr


class _FarmStarted(Exception):
    """Raised by the stand-in for LocalFarm: the test stops where the farm would start."""


def _demo_stderr(monkeypatch, capsys, cache: Path) -> str:
    import services.launcher

    def no_farm(*_args, **_kwargs):
        raise _FarmStarted

    monkeypatch.setenv("NUMBA_CACHE_DIR", str(cache))
    monkeypatch.setattr(services.launcher, "LocalFarm", no_farm)
    try:
        main(["demo", str(ROOT / "examples" / "cornell_box.json"), "-q"])
    except _FarmStarted:
        pass
    return capsys.readouterr().err


def test_demo_says_it_compiles_on_a_cold_cache_only(tmp_path, monkeypatch, capsys):
    """A cold `make demo` spends its first minute compiling; it says so rather than show a
    progress bar stuck at 0 %. With the warm-up's marker in the cache folder it says nothing."""
    from renderer import warm_marker

    cache = tmp_path / "cache"
    assert "compiling the renderer, first run only" in _demo_stderr(monkeypatch, capsys, cache)
    marker = warm_marker()
    assert marker.parent == cache
    cache.mkdir()
    marker.touch()
    assert "compiling" not in _demo_stderr(monkeypatch, capsys, cache)


def test_worker_and_up_take_pool_tags(capsys):
    import pytest

    from services.cli import build_parser

    parser = build_parser()
    assert parser.parse_args(["worker", "--redis", "redis://x", "--tags", "gpu, bigmem"]).tags \
        == ("bigmem", "gpu")
    assert parser.parse_args(["up", "--tags", "gpu"]).tags == ("gpu",)
    assert parser.parse_args(["submit", "s.json", "--tags", "gpu"]).tags == ("gpu",)
    for bad in ("GPU", "a,b,c,d,e,f"):
        with pytest.raises(SystemExit):
            parser.parse_args(["worker", "--redis", "redis://x", "--tags", bad])
    assert "--tags" in capsys.readouterr().err


def test_render_writes_aov_layers_and_denoises(tmp_path, capsys):
    pytest.importorskip("pyoidn")
    import OpenEXR

    data = json.loads(small_scene(tmp_path).read_text())
    data["film"]["aovs"] = ["albedo", "depth", "spp"]
    path = tmp_path / "aovs.json"
    path.write_text(json.dumps(data))
    out = tmp_path / "out.exr"
    assert main(["render", str(path), "-o", str(out), "--spp", "2", "--denoise", "-q"]) == 0
    err = capsys.readouterr().err
    assert "denoised" in err and "out_noisy.exr" in err
    noisy = tmp_path / "out_noisy.exr"
    for f in (out, noisy):
        channels = OpenEXR.File(str(f), separate_channels=True).channels()
        assert set(channels) == {"R", "G", "B", "albedo.R", "albedo.G", "albedo.B", "depth.Z",
                                 "spp.Y"}
        np.testing.assert_array_equal(channels["spp.Y"].pixels, 2.0)
    # the denoised image differs from the noisy one, which is the plain render's
    assert not np.array_equal(read_image(out), read_image(noisy))
    plain = tmp_path / "plain.exr"
    assert main(["render", str(small_scene(tmp_path)), "-o", str(plain), "--spp", "2",
                 "-q"]) == 0
    np.testing.assert_array_equal(read_image(noisy), read_image(plain))


def test_render_aovs_to_png_says_they_are_exr_only(tmp_path, capsys):
    data = json.loads(small_scene(tmp_path).read_text())
    data["film"]["aovs"] = ["normal"]
    path = tmp_path / "aovs.json"
    path.write_text(json.dumps(data))
    assert main(["render", str(path), "-o", str(tmp_path / "o.png"), "--spp", "1", "-q"]) == 0
    assert ".exr outputs only" in capsys.readouterr().err


def _sees_a_gpu() -> bool:
    from renderer.wavefront import gpu_missing

    return gpu_missing() is None


@pytest.mark.skipif(_sees_a_gpu(), reason="this machine has a CUDA GPU")
def test_the_gpu_kernel_where_no_gpu_is_seen_is_refused_with_the_reason(tmp_path, capsys,
                                                                         monkeypatch):
    """``lucent render``, ``lucent worker`` and ``lucent up`` with ``--kernel gpu`` on a machine
    without a CUDA GPU stop at once and say why (before Celery or the farm starts), instead of a
    render failing deep in numba or a node that fails every pass it takes."""
    scene = small_scene(tmp_path)
    assert main(["render", str(scene), "-o", str(tmp_path / "x.npy"), "--kernel", "gpu",
                 "-q"]) == 1
    assert "--kernel gpu: this process sees no CUDA GPU" in capsys.readouterr().err
    assert not (tmp_path / "x.npy").exists()
    # a translucent scene too, which the GPU renders with its path kernel, not the CPU unasked
    wax = json.loads((ROOT / "examples" / "translucent_sphere.json").read_text())
    wax["film"] = {"width": 4, "height": 3}
    (tmp_path / "wax.json").write_text(json.dumps(wax))
    assert main(["render", str(tmp_path / "wax.json"), "-o", str(tmp_path / "x.npy"),
                 "--kernel", "gpu", "-q"]) == 1
    assert "--kernel gpu: this process sees no CUDA GPU" in capsys.readouterr().err
    assert not (tmp_path / "x.npy").exists()
    monkeypatch.setattr(os, "execvpe", lambda *a: pytest.fail("the worker was started"))
    assert main(["worker", "--redis", "redis://127.0.0.1:1", "--kernel", "gpu"]) == 1
    assert "--kernel gpu: this process sees no CUDA GPU" in capsys.readouterr().err
    import services.launcher

    monkeypatch.setattr(services.launcher.LocalFarm, "start",
                        lambda *a, **k: pytest.fail("the farm was started"))
    assert main(["up", "--kernel", "gpu"]) == 1
    assert "--kernel gpu: this process sees no CUDA GPU" in capsys.readouterr().err


def test_worker_kernel_reaches_the_node_and_the_settings(monkeypatch):
    """``lucent worker --kernel wavefront`` starts Celery with LUCENT_WORKER_KERNEL set, which
    the settings read, and so does ``lucent up --kernel``'s worker node; a kernel the renderer
    does not have is refused by both."""
    import pydantic

    from services.cli import build_parser
    from services.farm.settings import Settings

    started = {}
    monkeypatch.setattr(os, "execvpe", lambda cmd, argv, env: started.update(env))
    main(["worker", "--redis", "redis://127.0.0.1:1", "--kernel", "wavefront"])
    assert started["LUCENT_WORKER_KERNEL"] == "wavefront"
    monkeypatch.setenv("LUCENT_WORKER_KERNEL", "wavefront")
    assert Settings().worker_kernel == "wavefront"
    monkeypatch.setenv("LUCENT_WORKER_KERNEL", "vulkan")
    with pytest.raises(pydantic.ValidationError, match="worker_kernel"):
        Settings()
    with pytest.raises(SystemExit):
        build_parser().parse_args(["worker", "--redis", "redis://x", "--kernel", "vulkan"])
    # The CLI's and the settings' lists of kernels are the renderer's
    from typing import get_args

    from renderer.render import KERNELS
    from services.cli import KERNELS as CLI_KERNELS

    assert CLI_KERNELS == KERNELS
    assert get_args(Settings.model_fields["worker_kernel"].annotation) == KERNELS
    # lucent up's worker node: the same variable, set by start_worker
    import subprocess

    import services.launcher

    assert build_parser().parse_args(["up", "--kernel", "wavefront"]).kernel == "wavefront"
    spawned = {}
    monkeypatch.setattr(subprocess, "Popen", lambda cmd, **kw: spawned.update(kw["env"]))
    services.launcher.start_worker("redis://127.0.0.1:1", 1, kernel="wavefront")
    assert spawned["LUCENT_WORKER_KERNEL"] == "wavefront"


def test_version_says_the_release_the_workers_heartbeat_gives(capsys):
    """``lucent --version``: the release (``renderer.__version__``), the one a worker's
    heartbeat gives and the dashboard's Workers page shows, to match a node against them."""
    from renderer import __version__

    with pytest.raises(SystemExit) as ended:
        main(["--version"])
    assert ended.value.code == 0
    assert capsys.readouterr().out == f"lucent {__version__}\n"
