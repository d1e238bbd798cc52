"""Render the Mitsuba 3 reference images that the accuracy tests compare Lucent against.

Not a test module (pytest collects ``test_*.py`` only). Run from the repository root::

    DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM-19.so \\
        .venv/bin/python -m tests.reference.generate

For each of ``examples/cornell_box.json`` and ``examples/glass_sphere.json``, at a reduced film of
64×48 (same camera, same vertical fov, same 4:3 aspect) and the scene's own ``max_depth``, it writes
to ``tests/data/`` (float32, H×W×3, linear RGB):

- ``<name>_ref.npy`` — the converged reference at 16384 spp (seed 0). Its noise standard deviation
  is √(64/16384) = 1/16 of a 64-spp image's (variance 1/256), so it inflates an RMSE measured
  against it at 64 spp by only √(1 + 1/256) − 1 ≈ 0.2 %. The two caustics (``REF_SPP``) take
  65536 spp: ``bench.target_error`` measures relMSE down to 0.002 against them, and Mitsuba's
  glass sphere at 16384 spp was itself 0.00085 relMSE from converged (its caustic's fireflies:
  0.00106 against a 65536-spp render), 0.0002 at 65536.
- ``<name>_spp64_seed{k}.npy`` for k = 1..4 — independent 64-spp images, so that a test can measure
  Mitsuba's own error at 64 spp (e.g. RMSE against ``_ref``) and hold Lucent to the same bar.

Measured on the development container (2 CPU cores shared with other jobs, ``llvm_ad_rgb``,
Mitsuba 3.9.1, LLVM 19), after a 1-spp warm-up render of each scene; two runs:

==============  ===============  ====================  ==========
scene           16384 spp ref    each 64 spp image     integrator
==============  ===============  ====================  ==========
cornell_box     11.7 s / 15.6 s  0.05 s / 0.10 s       path
glass_sphere    26.2 s / 33.7 s  0.35 s                volpath
==============  ===============  ====================  ==========

The chromatic scenes (``chromatic_wax``, ``chromatic_slab``) are split by channel, three
renders each (``renderer.mitsuba_bridge.render_mitsuba_split``): their 16384-spp references took
112 s and 61 s on the same machine. The rest of the script takes 40–52 s. The glass sphere needs
``volpath`` for its Beer–Lambert interior, hence slower. The scalar_rgb variant works too but is
several times slower; the script prints its own timings either way. The 64-spp images are bitwise
reproducible on one machine (on another CPU to float rounding: the glass sphere's, made again on
Z3, differed by at most 0.0026 in a pixel); the references are reproducible only to float
rounding (several passes accumulate into the film with parallel atomic adds, whose order
varies).
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
SCENES = ("cornell_box", "glass_sphere", "translucent_sphere", "backlit_slab", "dense_sphere",
          "chromatic_wax", "chromatic_slab", "env_diffuse_sphere", "env_rough_glass_sphere",
          "env_wax_sphere", "tex_bitmap_quad", "tex_checker_quad", "caustic_floor")
# The reference's spp where it is not --ref-spp: scenes whose relMSE is measured down to 0.002
# against it (bench.target_error) and whose caustic makes Mitsuba's 16384-spp image too noisy
REF_SPP = {"glass_sphere": 65536, "caustic_floor": 65536}
# Scenes with only a reference, no 64-spp images
REF_ONLY = ("dense_sphere", "caustic_floor")
# Scenes kept beside their references in tests/data/ (with the environment image they name,
# sky_64x32.exr: ``python examples/make_sky.py tests/data/sky_64x32.exr --width 64 --height 32
# --sun-radius 5``; the bitmap texture_16x16.png, a gradient with a dark band near its bottom and a
# bright mark in its top-left corner), already at the reference film size.
DATA_SCENES = ("env_diffuse_sphere", "env_rough_glass_sphere", "env_wax_sphere", "tex_bitmap_quad",
               "tex_checker_quad")
# Chromatic media (σt per channel): the reference is split by channel, three renders with the
# medium made grey at each channel's σt, channel k taken from the k-th (RGB transport is
# independent per channel). Mitsuba's RGB volpath samples a chromatic medium's flights from one
# channel without MIS over the channels and stays covered in coloured fireflies at 8192 spp, so it
# is no reference there (issue #25); the noisy images are split the same way, and are what
# "Mitsuba's own error" means for these scenes.
CHROMATIC = ("chromatic_wax", "chromatic_slab")
# dense_sphere: the translucent sphere made of a dense grey wax (albedo 0.95, σt 800, g 0, ior 1.4),
# a material auto renders as an opaque surface (tests/renderer/materials/test_opaque.py); only its
# reference is written.
DENSE_WAX = {"type": "translucent", "method": "volumetric", "ior": 1.4, "albedo": [0.95] * 3,
             "density": 800.0, "g": 0.0}
FILM = {"width": 64, "height": 48}
NOISY_SEEDS = (1, 2, 3, 4)
REF_SEED = 0


def _reduced(name: str) -> dict:
    """The example scene at the reference film size; everything else (max_depth too) unchanged."""
    if name in DATA_SCENES:
        return json.loads((ROOT / "tests" / "data" / f"{name}.json").read_text())
    example = "translucent_sphere" if name == "dense_sphere" else name
    scene = json.loads((ROOT / "examples" / f"{example}.json").read_text())
    scene = copy.deepcopy(scene)
    scene["film"] = dict(FILM)
    if name == "dense_sphere":
        scene["materials"]["wax"] = dict(DENSE_WAX)
    return scene


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ref-spp", type=int, default=16384,
                        help="spp of the converged reference (REF_SPP's scenes take theirs)")
    parser.add_argument("--spp", type=int, default=64, help="spp of the independent noisy images")
    parser.add_argument("--variant", default=None, help="Mitsuba variant (default: llvm if found)")
    parser.add_argument("--out", type=Path, default=ROOT / "tests" / "data")
    parser.add_argument("--scenes", nargs="+", default=list(SCENES), choices=SCENES,
                        help="which examples (default: all)")
    args = parser.parse_args(argv)

    if str(ROOT) not in sys.path:  # also runnable as a plain script
        sys.path.insert(0, str(ROOT))
    from renderer.mitsuba_bridge import default_variant, render_mitsuba, render_mitsuba_split

    variant = args.variant or default_variant()
    args.out.mkdir(parents=True, exist_ok=True)
    print(f"variant {variant}, film {FILM['width']}x{FILM['height']}, output {args.out}")
    print(f"{'scene':<14} {'image':<30} {'spp':>6} {'seconds':>8}  mean RGB")
    for name in args.scenes:
        scene = _reduced(name)
        # Warm-up: the first render of a scene JIT-compiles its kernels; keep that out of timings.
        base_dir = ROOT / "tests" / "data" if name in DATA_SCENES else None
        render_mitsuba(scene, spp=1, seed=REF_SEED, variant=variant, base_dir=base_dir)
        jobs = [(f"{name}_ref.npy", REF_SPP.get(name, args.ref_spp), REF_SEED)]
        if name not in REF_ONLY:
            jobs += [(f"{name}_spp{args.spp}_seed{k}.npy", args.spp, k) for k in NOISY_SEEDS]
        for filename, spp, seed in jobs:
            start = time.perf_counter()
            if name in CHROMATIC:
                img = render_mitsuba_split(scene, spp=spp, seed=seed, variant=variant)
            else:
                img = render_mitsuba(scene, spp=spp, seed=seed, variant=variant,
                                     base_dir=base_dir)
            seconds = time.perf_counter() - start
            if not np.all(np.isfinite(img)):
                raise RuntimeError(f"{filename}: non-finite pixels")
            np.save(args.out / filename, img.astype(np.float32))
            mean = ", ".join(f"{c:.4f}" for c in img.reshape(-1, 3).mean(axis=0))
            print(f"{name:<14} {filename:<30} {spp:>6} {seconds:>8.2f}  ({mean})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
