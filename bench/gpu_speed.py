"""Paths per second on a GPU: Lucent's CUDA kernels against its CPU kernels and Mitsuba 3, one run.

    python -m bench.gpu_speed [--scenes cornell_box glass_sphere] [--spp 256] [--repeats 3]
        [--batches 16 18 20 22] [--tails 0 0.25 1] [--grid] [--tile 64] [--tile-spp 16]
        [--ref-spp 4096] [--film WxH] [--json OUT.json]

Run it on a host with a CUDA GPU (numba.cuda sees it); it is how docs/performance.md's GPU table
was measured. For each scene (``examples/<name>.json`` at its own resolution):

- **gpu**: ``render_tile_gpu`` over the whole frame at ``--spp``. The first calls, at 1 spp,
  include compiling the CUDA kernels (``compile_seconds``); an empty launch of a stage is timed
  (``launch_seconds``: what passing the scene and path state costs). A scene the wavefront stages
  cover (``kernel``: ``stages``) is then timed at each batch size of ``--batches`` (paths a
  batch, as powers of two) at the default ``tail``, at each ``tail`` of ``--tails`` at the
  default batch size (with ``--grid``, every pair of the two too: ``by_pair``), and by
  ``path_kernel`` at the default batch size (``megakernel``); any other scene (``kernel``:
  ``path_kernel``) by ``path_kernel`` at each batch size. Best of ``--repeats``. A farm pass is
  timed too: one ``--tile`` × ``--tile`` tile at ``--tile-spp``.
- **cpu scalar**, **cpu wavefront** (the latter for the scenes it covers): ``render_buffer`` on
  every core of the host, at ``--spp``, best of ``--repeats`` after a 1-spp warm-up
  (``bench.cornell_speed.time_lucent``).
- **mitsuba cuda_ad_rgb** and **llvm_ad_rgb** (the optional extra; a variant that does not load is
  reported as unavailable): ``bench.mitsuba_side.time_mitsuba`` at ``--spp``.

Correctness on the device: each GPU kernel traces a CPU kernel's paths (the stages the wavefront
kernel's, ``path_kernel`` the scalar kernel's), so their images are compared pixel by pixel
(``gpu stages vs cpu wavefront``, ``gpu path_kernel vs cpu scalar``: the share of pixels equal
to 10⁻⁶ relative, and the relative difference of the two frame means); and each is scored
against a Mitsuba 3 reference of ``--ref-spp`` (cuda_ad_rgb, else llvm_ad_rgb; relMSE as
bench.accuracy's ``rel_mse``), so a GPU that computed something else would show a larger error
than the CPU kernel's at equal spp.
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


def time_gpu(compiled, spp: int, repeats: int, batches: list[int], tails: list[float],
             tile: int, tile_spp: int, grid: bool = False) -> dict:
    """The GPU's timings of one scene. A scene the stages cover is timed by batch size and by
    tail (and their grid), and by ``path_kernel`` too (``megakernel``); any other scene runs
    ``path_kernel`` only, by batch size."""
    from renderer.wavefront.cpu import unsupported
    from renderer.wavefront.gpu import GPU_BATCH_PATHS, TAIL, render_tile_gpu

    w, h = compiled.width, compiled.height
    staged = unsupported(compiled) is None
    start = time.perf_counter()
    if staged:
        render_tile_gpu(compiled, 0, 0, w, h, 0, 1, tail=0.5)  # the stages and the tail
    render_tile_gpu(compiled, 0, 0, w, h, 0, 1, megakernel=True)
    compile_seconds = time.perf_counter() - start
    launch_seconds = time_launch(compiled)
    images: dict[bool, object] = {}
    timed: dict[tuple[int, float, bool], dict] = {}

    def best_of(batch_paths: int, tail: float, megakernel: bool = not staged) -> dict:
        if (batch_paths, tail, megakernel) in timed:
            return timed[batch_paths, tail, megakernel]
        best = float("inf")
        for _ in range(repeats):
            start = time.perf_counter()
            buf = render_tile_gpu(compiled, 0, 0, w, h, 0, spp, batch_paths=batch_paths,
                                  tail=tail, megakernel=megakernel)
            best = min(best, time.perf_counter() - start)
        if megakernel not in images or (batch_paths == GPU_BATCH_PATHS and tail == TAIL):
            images[megakernel] = buf
        timed[batch_paths, tail, megakernel] = {"seconds": best,
                                                "paths_per_second": w * h * spp / best}
        return timed[batch_paths, tail, megakernel]

    by_batch = {b: best_of(1 << b, TAIL) for b in batches}
    by_tail = {t: best_of(GPU_BATCH_PATHS, t) for t in tails} if staged else {}
    # every batch size at every tail, where asked: the best pair need not lie on the two lines
    by_pair = ({f"2^{b} {t:g}": best_of(1 << b, t) for b in batches for t in tails}
               if grid and staged else {})
    megakernel = best_of(GPU_BATCH_PATHS, TAIL, True)
    tw, th = min(tile, w), min(tile, h)
    render_tile_gpu(compiled, 0, 0, tw, th, 0, tile_spp)
    best_tile = float("inf")
    for k in range(repeats):
        start = time.perf_counter()
        render_tile_gpu(compiled, 0, 0, tw, th, tile_spp * (k + 1), tile_spp)
        best_tile = min(best_tile, time.perf_counter() - start)
    return {"kernel": "stages" if staged else "path_kernel", "compile_seconds": compile_seconds,
            "launch_seconds": launch_seconds, "by_batch": by_batch, "by_tail": by_tail,
            "by_pair": by_pair, "megakernel": megakernel,
            "batch_paths": GPU_BATCH_PATHS, "tail": TAIL, "images": images,
            "tile": {"size": [tw, th], "spp": tile_spp, "seconds": best_tile,
                     "paths_per_second": tw * th * tile_spp / best_tile}}


def time_launch(compiled, launches: int = 100) -> float:
    """Seconds a launch of a stage takes with nothing to do (no live path): what passing the
    scene and path state to a kernel costs, paid once a stage a segment."""
    from numba import cuda

    from renderer.wavefront import gpu

    S = gpu._scene_on_device(compiled)
    P, live, _, _ = gpu._paths_on_device(1 << 10)
    gpu.shade_kernel[1, gpu.THREADS](S, P, live, 0, compiled.max_depth)  # compiled, if not yet
    cuda.synchronize()
    start = time.perf_counter()
    for _ in range(launches):
        gpu.shade_kernel[1, gpu.THREADS](S, P, live, 0, compiled.max_depth)
    cuda.synchronize()
    return (time.perf_counter() - start) / launches


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def compare(gpu_buf, cpu_buf) -> dict:
    """How far the GPU's sample buffer is from the CPU wavefront kernel's (the same paths)."""
    same_count = bool(np.array_equal(gpu_buf.count, cpu_buf.count))
    a, b = gpu_buf.mean(), cpu_buf.mean()
    close = np.isclose(a, b, rtol=1e-6, atol=1e-9).all(axis=-1)
    return {"same_counts": same_count, "pixels_equal_1e-6": float(close.mean()),
            "mean_relative_difference": float(abs(a.mean() - b.mean()) / b.mean())}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", nargs="+", default=["cornell_box", "glass_sphere"])
    parser.add_argument("--spp", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--batches", type=int, nargs="+", default=[16, 18, 20, 22],
                        help="paths a batch, as powers of two")
    parser.add_argument("--tails", type=float, nargs="+", default=[0.0, 0.25, 1.0],
                        help="shares of a batch live at which one launch finishes the rest")
    parser.add_argument("--grid", action="store_true",
                        help="time every batch size at every tail too (by_pair)")
    parser.add_argument("--tile", type=int, default=64)
    parser.add_argument("--tile-spp", type=int, default=16)
    parser.add_argument("--ref-spp", type=int, default=4096)
    parser.add_argument("--variants", nargs="*", default=["cuda_ad_rgb", "llvm_ad_rgb"])
    parser.add_argument("--film", help="WxH instead of each scene's resolution (a smoke run on "
                        "numba's CUDA simulator: NUMBA_ENABLE_CUDASIM=1 NUMBA_DISABLE_JIT=1)")
    parser.add_argument("--json", help="write the results here too")
    args = parser.parse_args()

    from numba import cuda

    from bench.accuracy import rel_mse
    from bench.cornell_speed import time_lucent
    from renderer.render import render_buffer
    from renderer.scene import load_scene
    from renderer.scene.compile import compile_scene

    if not cuda.is_available():
        print("no CUDA GPU is visible to numba.cuda: nothing to measure")
        return 1
    if os.environ.get("NUMBA_ENABLE_CUDASIM") == "1":
        gpu, cc = "numba's CUDA simulator", [0, 0]
    else:
        device = cuda.get_current_device()
        gpu = device.name.decode() if isinstance(device.name, bytes) else str(device.name)
        cc = list(device.compute_capability)
    host = {"gpu": gpu, "compute_capability": cc, "cpu_cores": os.cpu_count(), "cpu": cpu_model()}
    print(f"GPU {host['gpu']} (cc {host['compute_capability']}), {host['cpu_cores']} CPU cores")
    results: dict = {"host": host, "spp": args.spp, "scenes": {}}

    def save() -> None:
        if args.json:
            Path(args.json).write_text(json.dumps(results, indent=1))

    for name in args.scenes:
        scene = json.loads((ROOT / "examples" / f"{name}.json").read_text())
        if args.film:
            fw, fh = (int(v) for v in args.film.lower().split("x"))
            scene["film"] = {**scene["film"], "width": fw, "height": fh}
        compiled = compile_scene(load_scene(scene))
        w, h = compiled.width, compiled.height
        print(f"\n{name}: {w}x{h}, {args.spp} spp")
        row: dict = {"size": [w, h]}
        results["scenes"][name] = row
        g = time_gpu(compiled, args.spp, args.repeats, args.batches, args.tails, args.tile,
                     args.tile_spp, args.grid)
        images = g.pop("images")
        row["gpu"] = g
        print(f"  gpu ({g['kernel']}): compile {g['compile_seconds']:.1f} s; a launch "
              f"{g['launch_seconds'] * 1e3:.2f} ms; " + ", ".join(
            f"2^{b} paths a batch {r['paths_per_second'] / 1e6:.1f} Mpaths/s"
            for b, r in g["by_batch"].items())
            + "".join(f"; tail {t:g} {r['paths_per_second'] / 1e6:.1f} Mpaths/s"
                      for t, r in g["by_tail"].items())
            + "".join(f"; {k} {r['paths_per_second'] / 1e6:.1f}" for k, r in g["by_pair"].items())
            + f"; path_kernel {g['megakernel']['paths_per_second'] / 1e6:.1f} Mpaths/s"
            + f"; a {g['tile']['size'][0]}x{g['tile']['size'][1]} tile × {args.tile_spp} spp "
              f"{g['tile']['paths_per_second'] / 1e6:.2f} Mpaths/s")
        save()
        ref = None
        for variant in args.variants:
            try:
                from bench.mitsuba_side import time_mitsuba
                from renderer.mitsuba_bridge import render_mitsuba

                r = time_mitsuba(scene, args.spp, variant, args.repeats)
                row[f"mitsuba {variant}"] = r
                print(f"  mitsuba {variant}: {r['paths_per_second'] / 1e6:.2f} Mpaths/s "
                      f"(warm-up {r['warmup_seconds']:.1f} s)")
                if ref is None:
                    ref = render_mitsuba(scene, args.ref_spp, seed=99, variant=variant)
                    row["reference"] = {"variant": variant, "spp": args.ref_spp}
            except Exception as err:  # the optional extra, or a variant that does not load
                row[f"mitsuba {variant}"] = {"unavailable": f"{type(err).__name__}: {err}"[:300]}
                print(f"  mitsuba {variant}: unavailable ({type(err).__name__}: {err})")
            save()
        # the CPU kernel whose paths each GPU kernel traces: the stages are the wavefront
        # kernel's, path_kernel is the scalar kernel's (which the wavefront kernel falls back to)
        staged = g["kernel"] == "stages"
        for kernel in ("wavefront", "scalar") if staged else ("scalar",):
            r = time_lucent(scene, args.spp, args.repeats, kernel)
            row[f"cpu {kernel}"] = r
            print(f"  cpu {kernel}: {r['paths_per_second'] / 1e6:.2f} Mpaths/s "
                  f"(warm-up {r['warmup_seconds']:.1f} s)")
            save()
        row["rel_mse"] = {}
        for megakernel, image in images.items():
            kernel = "scalar" if megakernel else "wavefront"
            cpu_buf = render_buffer(compiled, args.spp, kernel=kernel)
            label = "path_kernel" if megakernel else "stages"
            row[f"gpu {label} vs cpu {kernel}"] = compare(image, cpu_buf)
            print(f"  gpu {label} vs cpu {kernel}: {row[f'gpu {label} vs cpu {kernel}']}")
            if ref is not None:
                row["rel_mse"][f"gpu {label}"] = rel_mse(image.mean(), ref)
                row["rel_mse"][f"cpu {kernel}"] = rel_mse(cpu_buf.mean(), ref)
            save()
        if ref is not None:
            print(f"  relMSE against the reference at {args.spp} spp: {row['rel_mse']}")
    print("\n" + json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
