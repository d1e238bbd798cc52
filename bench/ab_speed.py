"""A/B: the renderer's speed in the working tree against a commit, and whether images changed.

    .venv/bin/python -m bench.ab_speed [--base HEAD] [--rounds 3] [--kernel scalar|packet|wavefront]
        [--scenes cornell_box ...]

On a shared 2-core VM one render's time moves by ±5 % from run to run, more than most single
optimizations gain, so one before and one after prove little. This script checks the base commit
out into a temporary ``git worktree`` and alternates the two renderers, ``--rounds`` times each,
every run a fresh process (``PYTHONPATH`` picks the checkout; each has its own numba cache folder,
keyed by its sources, under the shared ``LUCENT_CACHE_DIR``). Every run renders each scene's full
frame with ``render_tile`` (best of 3 after a warm-up) and reports paths/s; the sample buffers
(sums, squares, counts) of the working tree are compared bit for bit with the base's (and where
they differ, the share of pixels that do and the relative L1 distance of the sums are printed).
Scenes are names of ``examples/*.json`` or paths of scene files (``bench/ab_scenes/*.json``: one
for each method the examples leave out). Prints the
median of each side and the ratio. An optimization that is only an optimization keeps
"identical"; docs/performance.md records what was measured this way.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENES = {"cornell_box": 32, "seed_paper_boxes_low_density": 16, "translucent_sphere": 16,
          "mesh_torus": 16}


def scene_path(name: str) -> Path:
    """An example's name, or a scene file's path."""
    return Path(name) if name.endswith(".json") else ROOT / "examples" / f"{name}.json"


def measure(scenes: list[str], out: Path, kernel: str = "scalar") -> None:
    """One run in this process: paths/s per scene, buffers saved for the comparison."""
    from renderer.render import _as_compiled, render_tile
    from renderer.scene.load import load_scene_file

    result = {}
    for name in scenes:
        cs = _as_compiled(load_scene_file(scene_path(name)))
        spp = SCENES.get(name, 16)
        render_tile(cs, 0, 0, cs.width, cs.height, 0, 1, kernel=kernel)
        best = float("inf")
        for _ in range(3):
            start = time.perf_counter()
            buf = render_tile(cs, 0, 0, cs.width, cs.height, 0, spp, kernel=kernel)
            best = min(best, time.perf_counter() - start)
        result[name] = cs.width * cs.height * spp / best
        np.savez(out / f"{Path(name).stem}.npz", sum=buf.sum, sum_sq=buf.sum_sq,
                 count=buf.count)
    (out / "speed.json").write_text(json.dumps(result))


def run(tree: Path, scenes: list[str], out: Path, kernel: str) -> dict[str, float]:
    out.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, PYTHONPATH=str(tree))
    env.pop("NUMBA_CACHE_DIR", None)  # each checkout keys its own cache folder by its sources
    # This file runs as a script (the base commit may not have it); the renderer it imports is
    # the checkout's, through PYTHONPATH
    subprocess.run([sys.executable, str(Path(__file__).resolve()), "--measure", str(out),
                    "--kernel", kernel, "--scenes", *scenes], check=True, cwd=tree, env=env)
    return json.loads((out / "speed.json").read_text())


def compare(a: Path, b: Path) -> str:
    """"identical" when the buffers are equal bit for bit, else how far the images are apart: the
    share of pixels whose sum differs and the relative L1 distance of the sums."""
    with np.load(a) as x, np.load(b) as y:
        if all(np.array_equal(x[k], y[k]) for k in ("sum", "sum_sq", "count")):
            return "identical"
        differ = np.any(x["sum"] != y["sum"], axis=-1).mean()
        l1 = np.abs(x["sum"] - y["sum"]).sum() / max(np.abs(x["sum"]).sum(), 1e-300)
        return f"IMAGES DIFFER: {differ:.2%} of pixels, relative L1 {l1:.2e}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--base", default="HEAD", help="commit to compare the working tree with")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--scenes", nargs="+", default=list(SCENES))
    parser.add_argument("--kernel", default="scalar",
                        choices=("scalar", "packet", "wavefront", "gpu"),
                        help="render_tile's kernel on both sides")
    parser.add_argument("--measure", metavar="OUT", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.measure:
        measure(args.scenes, Path(args.measure), args.kernel)
        return 0
    speeds: dict[str, dict[str, list[float]]] = {"base": {}, "new": {}}
    same = {name: "identical" for name in args.scenes}
    with tempfile.TemporaryDirectory() as tmp:
        base_tree = Path(tmp) / "base"
        subprocess.run(["git", "worktree", "add", "--detach", "-q", str(base_tree), args.base],
                       check=True, cwd=ROOT)
        try:
            for r in range(args.rounds):
                for side, tree in (("base", base_tree), ("new", ROOT)):
                    out = Path(tmp) / f"{side}{r}"
                    for name, v in run(tree, args.scenes, out, args.kernel).items():
                        speeds[side].setdefault(name, []).append(v)
                    if side == "new":
                        for name in args.scenes:
                            stem = Path(name).stem
                            verdict = compare(Path(tmp) / f"base{r}" / f"{stem}.npz",
                                              out / f"{stem}.npz")
                            if verdict != "identical":
                                same[name] = verdict
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(base_tree)], cwd=ROOT)
    print(f"working tree against {args.base}, {args.kernel} kernel, {args.rounds} alternating "
          "rounds, M paths/s "
          "(full frame, best of 3 renders a run); median, then every run")
    for name in args.scenes:
        b = statistics.median(speeds["base"][name]) / 1e6
        n = statistics.median(speeds["new"][name]) / 1e6
        runs = " ".join(f"{v / 1e6:.2f}" for v in speeds["base"][name])
        runs_new = " ".join(f"{v / 1e6:.2f}" for v in speeds["new"][name])
        print(f"{name:30s} base {b:5.2f} ({runs})  new {n:5.2f} ({runs_new})  "
              f"new/base {n / b:.3f}  {same[name]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
