"""The chromatic walk against the channel-split render: error at equal spp and at equal time.

    .venv/bin/python -m bench.chromatic_split [--spp 256] [--seeds 4]

For each chromatic example with a split Mitsuba 3 reference in ``tests/data`` (``chromatic_wax``,
``chromatic_slab``; ``python -m tests.reference.generate``), at the reference's 64×48: Lucent's
one chromatic render against Lucent's own split render (three renders with the medium grey at
each channel's σt, channel k from the k-th: ``renderer.mitsuba_bridge.grey_at_channel``), both at
``--spp``, over ``--seeds`` seeds: the MSE of each against the reference, their ratio at equal
spp, the seconds of each (warm), and MSE × seconds, the ratio at equal time. Record results in
docs/methods/volumetric.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spp", type=int, default=256)
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--scenes", nargs="+", default=["chromatic_wax", "chromatic_slab"])
    args = parser.parse_args(argv)
    from renderer.mitsuba_bridge import grey_at_channel
    from renderer.render import render

    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs; "
          f"{args.spp} spp, {args.seeds} seeds, 64x48")
    for name in args.scenes:
        ref = np.load(ROOT / "tests" / "data" / f"{name}_ref.npy").astype(np.float64)
        scene = json.loads((ROOT / "examples" / f"{name}.json").read_text())
        scene["film"] = {"width": ref.shape[1], "height": ref.shape[0]}
        render(dict(scene, render=dict(scene["render"], spp=1)))  # warm the kernels
        mse = {"chromatic": [], "split": []}
        secs = {"chromatic": 0.0, "split": 0.0}
        for seed in range(1, args.seeds + 1):
            scene["render"].update(spp=args.spp, seed=seed)
            start = time.perf_counter()
            img = render(scene)
            secs["chromatic"] += time.perf_counter() - start
            mse["chromatic"].append(np.mean((img - ref) ** 2))
            start = time.perf_counter()
            split = render(grey_at_channel(scene, 0))
            for k in (1, 2):
                split[..., k] = render(grey_at_channel(scene, k))[..., k]
            secs["split"] += time.perf_counter() - start
            mse["split"].append(np.mean((split - ref) ** 2))
        m = {k: float(np.mean(v)) for k, v in mse.items()}
        print(f"{name}: chromatic MSE {m['chromatic']:.5f} in {secs['chromatic']:.2f} s, split "
              f"MSE {m['split']:.5f} in {secs['split']:.2f} s; equal spp "
              f"{m['chromatic'] / m['split']:.2f}, equal time "
              f"{m['chromatic'] * secs['chromatic'] / (m['split'] * secs['split']):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
