"""Adaptive sampling against uniform sampling: time to equal error.

    .venv/bin/python -m bench.adaptive [--scenes cornell_box backlit_slab ...]

For each example with a Mitsuba reference in tests/data (64×48), renders uniformly at 16…1024 spp
and adaptively at several ``render.target_error`` values (spp cap 1024), measures each image's
relative MSE against the reference, mean((x − ref)²/(ref² + 0.01)), and the wall time (best of 2,
warm JIT). The uniform time at the adaptive run's error is interpolated on the log–log curve;
"saved" is 1 − t_adaptive / t_uniform at equal error (negative: adaptive was slower). Also prints
the frame-mean ratio to the reference (the stopping rule's bias shows there).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def run(data: dict) -> tuple[float, float, float, float]:
    from renderer.render import render_buffer
    from renderer.scene import load_scene
    from renderer.scene.compile import compile_scene

    cs = compile_scene(load_scene(data))
    best = np.inf
    for _ in range(2):
        t = time.perf_counter()
        buf = render_buffer(cs)
        best = min(best, time.perf_counter() - t)
    return best, buf.sum / np.maximum(buf.count, 1)[..., None], float(buf.count.mean()), 0.0


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scenes", nargs="+",
                        default=["cornell_box", "backlit_slab", "translucent_sphere"])
    args = parser.parse_args()
    from renderer.render import render_buffer
    from renderer.scene import load_scene

    print(f"{'scene':<20} {'mode':<14} {'mean spp':>8} {'seconds':>8} {'relMSE':>9} "
          f"{'uniform s':>9} {'saved':>7} {'mean/ref':>9}")
    for name in args.scenes:
        ref = np.load(ROOT / "tests" / "data" / f"{name}_ref.npy").astype(np.float64)
        base = json.loads((ROOT / "examples" / f"{name}.json").read_text())
        base["film"] = {"width": 64, "height": 48}
        render_buffer(load_scene(base), 1)  # warm the JIT

        def rel(img, ref=ref):
            return float(np.mean((img - ref) ** 2 / (ref**2 + 0.01)))

        uniform = []
        for spp in (16, 32, 64, 128, 256, 512, 1024):
            data = json.loads(json.dumps(base))
            data["render"].update(spp=spp, seed=7)
            t, img, mean_spp, _ = run(data)
            uniform.append((t, rel(img)))
            print(f"{name:<20} {'uniform':<14} {mean_spp:>8.0f} {t:>8.3f} {rel(img):>9.5f} "
                  f"{'':>9} {'':>7} {img.mean() / ref.mean():>9.4f}")
        ut = np.log([u[0] for u in uniform])
        ue = np.log([u[1] for u in uniform])
        for target in (0.05, 0.02, 0.01, 0.005):
            data = json.loads(json.dumps(base))
            data["render"].update(spp=1024, seed=7, target_error=target)
            t, img, mean_spp, _ = run(data)
            e = rel(img)
            # uniform error falls with time: interpolate log t at log e (np.interp needs ascending)
            t_uniform = float(np.exp(np.interp(np.log(e), ue[::-1], ut[::-1])))
            saved = 1 - t / t_uniform
            print(f"{name:<20} {'target ' + str(target):<14} {mean_spp:>8.0f} {t:>8.3f} "
                  f"{e:>9.5f} {t_uniform:>9.3f} {saved:>7.0%} {img.mean() / ref.mean():>9.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
