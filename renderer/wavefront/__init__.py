"""The batched (wavefront) path tracer for surface scenes.

Paths are traced a batch at a time, one stage after the other over all of them, in the order of
pbrt-v4's wavefront integrator (Pharr, Jakob & Humphreys, "Physically Based Rendering", 4th ed.,
ch. 15): generate camera rays, find each ray's closest hit, handle escaped rays and emitters and
sample the BSDF and a light (``shade``), trace the light samples' shadow rays, compact the live
paths, and at the end accumulate each path's radiance into the tile's sample buffer.

- ``state``: the paths' structure-of-arrays state (``PathState``).
- ``stages``: each stage's work on one path (``*_one``), a pure function of the scene and state
  arrays and a path index, and the CPU stages that run it over a queue of paths in parallel.
- ``cpu``: the host loop on the CPU (``render_tile_wavefront``) and which scenes it takes
  (``unsupported``); other scenes are rendered by the scalar kernel.
- ``gpu``: the same stages as numba.cuda kernels, calling the same per-path functions.
"""


def gpu_missing() -> str | None:
    """Why this process cannot run the ``gpu`` kernel, or None when it can (imports numba.cuda,
    which is left to the processes that ask)."""
    try:
        from numba import cuda
    except ImportError as err:  # a numba without its CUDA target
        return f"numba.cuda does not import ({err})"
    if not cuda.is_available():
        return ("this process sees no CUDA GPU and driver (numba.cuda.is_available() is false); "
                "the scalar and wavefront kernels run on the CPU")
    return None
