"""Host entry points: ``render_tile`` (the farm's unit of work) and ``render`` (a whole frame)."""

from __future__ import annotations

import time
from collections.abc import Callable

import numba
import numpy as np

from renderer.film.adaptive import noise_target, sample_to_target
from renderer.film.buffer import SampleBuffer
from renderer.integrators.path import render_tile_kernel
from renderer.packet import render_tile_packet
from renderer.packet import unsupported as packet_unsupported
from renderer.scene.compile import CompiledScene, compile_scene
from renderer.wavefront.cpu import pixel_counts, render_tile_wavefront, unsupported

KERNELS = ("scalar", "wavefront", "gpu", "packet")  # render_tile's kernels (the CLI's --kernel)


def render_tile(
    scene: CompiledScene,
    x0: int,
    y0: int,
    width: int,
    height: int,
    sample_start: int,
    sample_count: int,
    active: np.ndarray | None = None,
    kernel: str = "packet",
) -> SampleBuffer:
    """Render samples [sample_start, sample_start + sample_count) of every pixel of a tile.

    Sample indices are global: the same (pixel, index) always gives the same sample, so a tile
    rendered as passes 0–7 and 8–15 adds up to the tile rendered as 0–15. ``active`` (h, w)
    limits the pass to the pixels where it is true (a bool or uint8 mask), or gives each pixel
    its number of samples, the first ones of the range (integers; adaptive sampling). ``kernel`` is
    ``"packet"`` (the default: 16 paths at once in float32 vector lanes, ``renderer.packet``,
    for flat scenes of diffuse and grey single_scatter materials lit by emitting surfaces, under
    either sampler; the scalar kernel renders the others), ``"scalar"`` (one path at a time,
    every method), ``"wavefront"`` (batches of paths stage by stage, ``renderer.wavefront``; it
    renders the scenes it covers, surface materials and the independent sampler, and leaves the
    others to the scalar kernel) or ``"gpu"`` (this process's CUDA GPU, every scene: the
    wavefront stages where they cover it, else the scalar kernel's path function one thread a
    path; ``renderer.wavefront.gpu``).
    """
    if kernel not in KERNELS:
        raise ValueError(f"kernel must be one of {KERNELS}, not {kernel!r}")
    if width < 0 or height < 0 or sample_start < 0 or sample_count < 0:
        raise ValueError("tile sizes and sample ranges must be non-negative")
    if x0 < 0 or y0 < 0 or x0 + width > scene.width or y0 + height > scene.height:
        raise ValueError(
            f"tile ({x0}, {y0}, {width}x{height}) outside the {scene.width}x{scene.height} frame"
        )
    if active is not None and active.shape != (height, width):
        raise ValueError(f"active mask of shape {active.shape} for a {width}x{height} tile")
    counts = pixel_counts(active, sample_count, height, width)
    if kernel == "gpu":
        # numba.cuda is imported only by a process that renders on a GPU
        from renderer.wavefront.gpu import render_tile_gpu

        return render_tile_gpu(scene, x0, y0, width, height, sample_start, sample_count, counts)
    if kernel == "packet" and scene.derived("packet_unsupported", packet_unsupported) is None:
        return render_tile_packet(scene, x0, y0, width, height, sample_start, counts)
    if kernel == "wavefront" and scene.derived("wavefront_unsupported", unsupported) is None:
        return render_tile_wavefront(scene, x0, y0, width, height, sample_start, sample_count,
                                     counts)
    buf = SampleBuffer.empty(x0, y0, width, height)
    if width and height and sample_count:
        render_tile_kernel(
            scene.arrays, scene.width, scene.height, scene.seed, scene.max_depth,
            scene.stack_size, x0, y0, width, height, sample_start, sample_count,
            np.ascontiguousarray(counts), buf.sum, buf.sum_sq, buf.count,
            buf.dropped, buf.segments, numba.get_num_threads(),
        )
    return buf


def _as_compiled(scene) -> CompiledScene:
    if isinstance(scene, CompiledScene):
        return scene
    if isinstance(scene, dict):
        from renderer.scene import load_scene

        scene = load_scene(scene)
    return compile_scene(scene)


def render_buffer(
    scene,
    spp: int | None = None,
    *,
    threads: int | None = None,
    pass_spp: int | None = None,
    progress: Callable[[int, int, float], None] | None = None,
    kernel: str = "packet",
    plan: Callable[[float, float], None] | None = None,
    even: bool = False,
) -> SampleBuffer:
    """Render a whole frame in passes of ``pass_spp`` samples per pixel.

    ``progress(samples_done, samples_total, seconds)`` is called after every pass (per pixel
    samples × pixels), which is what the CLI's progress bar shows. With the scene's
    ``render.target_error`` (the frame's expected relMSE, ``renderer.film.adaptive``) a pilot
    is followed by passes to the pixels whose allocation exceeds what they have, each pixel at
    most ``spp`` samples; ``plan(mean_spp, error)`` is told the pilot's allocation and the
    error it expects of it (the samples' noise); ``even`` makes every pass give every pixel the
    same count (``sample_to_target``). ``kernel``: see ``render_tile``.
    """
    cs = _as_compiled(scene)
    spp = cs.spp if spp is None else spp
    if threads is not None:
        numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
    if pass_spp is None:
        # Aim at passes of ~2 M samples so the progress bar moves about once a second
        pass_spp = max(1, min(spp, 2_000_000 // max(1, cs.width * cs.height)))
    frame = SampleBuffer.empty(0, 0, cs.width, cs.height)
    start = time.perf_counter()
    if cs.target_error is not None:
        def render_pass(index: int, counts: np.ndarray) -> SampleBuffer:
            return render_tile(cs, 0, 0, cs.width, cs.height, index, int(counts.max()), counts,
                               kernel)

        def report(done: int, planned: int) -> None:
            if progress is not None:
                progress(done, planned, time.perf_counter() - start)

        # (the samples' share of the target: auto's models may take some of it)
        return sample_to_target(render_pass, (cs.height, cs.width),
                                noise_target(cs.target_error, cs.expected_bias), spp,
                                plan=plan, progress=report, max_pass=pass_spp, even=even)
    done = 0
    while done < spp:
        n = min(pass_spp, spp - done)
        frame.add(render_tile(cs, 0, 0, cs.width, cs.height, done, n, None, kernel))
        done += n
        if progress is not None:
            progress(done * cs.width * cs.height, spp * cs.width * cs.height,
                     time.perf_counter() - start)
    return frame


def render(scene, spp: int | None = None, *, threads: int | None = None,
           kernel: str = "packet") -> np.ndarray:
    """Render a scene (dict, validated ``Scene`` or ``CompiledScene``) to an HxWx3 float32 image
    (``kernel``: see ``render_tile``)."""
    return render_buffer(scene, spp, threads=threads, kernel=kernel).mean()
