"""What each worker process keeps: its store connection, compiled scenes, JIT warm-up, heartbeat.

Celery's prefork pool forks after importing the app, so everything here is created lazily in the
pool process (``worker_process_init``), never in the parent: Redis connections and numba's thread
pool must not cross a fork.
"""

from __future__ import annotations

import logging
import os
import socket
import subprocess
import sys
import threading
import time
from collections import OrderedDict
from pathlib import Path
from typing import Any

from renderer import __version__, warm_marker
from services.farm.blobs import AssetCache, open_blob_store
from services.farm.settings import get_settings
from services.farm.store import MERGE_PROTOCOL, JobStore

log = logging.getLogger(__name__)

# This worker node's Celery name (``n0@host``), set in the node's main process before the pool
# forks (``worker.tasks``, ``worker_init``): the unit the blocklist counts failures of.
NODE = ""

# A scene small enough to render in milliseconds that still runs every kernel the tile renderer
# calls (a quad light over a diffuse sphere), to load numba's cached machine code before the
# first real task.
WARM_UP_SCENE: dict[str, Any] = {
    "camera": {"position": [0, 0, 3], "look_at": [0, 0, 0], "fov": 40},
    "film": {"width": 4, "height": 4},
    "render": {"spp": 1, "max_depth": 2, "seed": 1},
    "materials": {"white": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
    "objects": [
        {"type": "sphere", "center": [0, 0, 0], "radius": 0.5, "material": "white"},
        {"type": "quad", "origin": [-0.5, 1, -0.5], "edge1": [1, 0, 0], "edge2": [0, 0, 1],
         "material": "white", "emission": [4, 4, 4]},
    ],
}


def warm_up_kernels(kernel: str = "packet", scalar: bool = True, mark: bool = True) -> float:
    """Render the warm-up scene once with the scalar kernel and run the adaptive rule's kernels
    (loads or compiles them), and mark the cache folder warm; returns seconds. With another
    ``kernel`` (the node's ``worker_kernel``) it is rendered with that one too: with
    ``wavefront`` the scalar kernel stays the one for scenes it does not cover; with ``gpu`` the
    path kernel, which renders those on the GPU, is compiled as well; with ``packet`` the scene's
    light alone is rendered (the packet kernel draws no spheres). ``scalar=False``: that kernel
    alone (``prewarm_cache`` compiles the two at once); ``mark=False``: the cache is not marked.
    The CUDA kernels are not cached on disk (their ``cuda.jit`` has no ``cache=True``), so each
    pool process of a GPU node compiles them here (docs/performance.md, "On a GPU")."""
    from renderer.film import adaptive
    from renderer.render import render_tile
    from renderer.scene import load_scene
    from renderer.scene.compile import compile_scene

    t0 = time.perf_counter()
    compiled = compile_scene(load_scene(WARM_UP_SCENE))
    if scalar:
        render_tile(compiled, 0, 0, 4, 4, 0, 1, kernel="scalar")
        adaptive.warm_up()
    if kernel in ("wavefront", "gpu"):
        render_tile(compiled, 0, 0, 4, 4, 0, 1, kernel=kernel)
    if kernel == "packet":
        # the warm-up scene's sphere is the scalar kernel's: the packet kernel's on its light
        quads = {**WARM_UP_SCENE,
                 "objects": [o for o in WARM_UP_SCENE["objects"] if o["type"] == "quad"]}
        render_tile(compile_scene(load_scene(quads)), 0, 0, 4, 4, 0, 1, kernel=kernel)
    if kernel == "gpu":
        from renderer.wavefront.gpu import render_tile_gpu

        render_tile_gpu(compiled, 0, 0, 4, 4, 0, 1, megakernel=True)
    seconds = time.perf_counter() - t0
    if mark:
        mark_warm()
    return seconds


def mark_warm() -> None:
    """Mark the cache folder warm (``warm_marker``)."""
    try:
        marker = warm_marker()
        marker.parent.mkdir(parents=True, exist_ok=True)
        marker.touch()
    except OSError as err:  # a read-only cache folder: the kernels are loaded all the same
        log.warning("could not mark the kernel cache warm: %s", err)


_WARM_UP = ("import sys; from worker.runtime import warm_up_kernels; "
            "warm_up_kernels(sys.argv[1], sys.argv[2] == 'scalar', False)")


def prewarm_cache(kernel: str = "packet", timeout: float = 1800.0) -> float | None:
    """Fill a cold kernel cache once per worker node, before the prefork pool forks.

    In child processes (the parent's numba must not start threads that a fork would copy), and
    only when there is no ``warm_marker()``: with a warm cache it costs nothing. The pool processes
    then load the kernels (~1.5 s) instead of each compiling them (~60 s each: N times the CPU,
    and with more pool processes than cores, longer than one compile); and a pool process started
    in place of one that died while the others were still compiling does not have to compile
    within Celery's ``worker_proc_alive_timeout``. Returns the seconds it took, or None when the
    cache was warm or a child failed (the pool processes then compile as before).
    ``kernel``: the node's ``worker_kernel``, whose CPU kernels are compiled (a GPU node's CUDA
    kernels are not cached on disk: its pool processes compile those). A packet node's two
    kernels compile at once, in two children (the packet kernel's ~8 s beside the scalar
    kernel's ~35 s on two cores, not after it); the cache is marked warm once both are done."""
    if warm_marker().exists():
        return None
    kernel = "scalar" if kernel == "gpu" else kernel
    # (the kernel, whether the child renders the scalar kernel too)
    parts = [("scalar", "scalar"), ("packet", "alone")] if kernel == "packet" \
        else [(kernel, "scalar")]
    t0 = time.perf_counter()
    children = []
    try:
        children = [subprocess.Popen([sys.executable, "-c", _WARM_UP, k, with_scalar])
                    for k, with_scalar in parts]
        codes = [child.wait(timeout=max(1.0, timeout - (time.perf_counter() - t0)))
                 for child in children]
    except (OSError, subprocess.SubprocessError) as err:
        for child in children:
            child.kill()
        log.warning("could not fill the kernel cache before the pool started: %s", err)
        return None
    if any(codes):
        log.warning("could not fill the kernel cache before the pool started: exit codes %s",
                    codes)
        return None
    mark_warm()
    return time.perf_counter() - t0


class WorkerState:
    """Per-process state; ``STATE`` below is this process's."""

    def __init__(self) -> None:
        self.settings = get_settings()
        self._store: JobStore | None = None
        self._compiled: OrderedDict[str, Any] = OrderedDict()
        self._assets: AssetCache | None = None
        self.worker_id = f"{socket.gethostname()}:{os.getpid()}"
        self.state = "starting"
        self.current_task = ""
        self.tiles_done = 0
        self.paths = 0
        self.render_seconds = 0.0
        self.started = time.time()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._beat: threading.Thread | None = None

    @property
    def assets(self) -> AssetCache:
        """The assets scenes reference: the blob store (the service's data folder, a volume the
        workers share), through this process's on-disk cache (``LUCENT_ASSET_CACHE_BYTES``)."""
        if self._assets is None:
            base = os.environ.get("LUCENT_CACHE_DIR") or Path(
                os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "lucent"
            self._assets = AssetCache(open_blob_store(self.settings.blob_location),
                                      Path(base) / "assets",
                                      self.settings.asset_cache_bytes)
        return self._assets

    @property
    def store(self) -> JobStore:
        if self._store is None:
            self._store = JobStore.from_url(self.settings.redis_url, self.settings.key_prefix)
        return self._store

    # --- compiled scenes (LRU by job id, or ``job/frame`` for a job of frames) ---------------
    def cached(self, job_id: str):
        """The job's ``CompiledScene`` if this process has compiled it, else None (a job's scene
        never changes, so a cached one needs no fetch of the scene from Redis: for a scene with
        a large inline mesh that fetch would cost more than the pass)."""
        with self._lock:
            compiled = self._compiled.get(job_id)
            if compiled is not None:
                self._compiled.move_to_end(job_id)
            return compiled

    def compiled(self, job_id: str, scene_json: dict):
        """The job's ``CompiledScene``, compiled once per process. Raises ``SceneError`` or
        ``CompileError`` for a scene that cannot be rendered."""
        cached = self.cached(job_id)
        if cached is not None:
            return cached
        from renderer.scene import load_scene
        from renderer.scene.compile import compile_scene

        compiled = compile_scene(load_scene(scene_json, assets=self.assets.read))
        with self._lock:
            self._compiled[job_id] = compiled
            while len(self._compiled) > self.settings.compiled_cache_size:
                self._compiled.popitem(last=False)
        return compiled

    # --- JIT warm-up ----------------------------------------------------------------------------
    def warm_up(self) -> float:
        """Render the warm-up scene once (loads or compiles the kernels); returns seconds."""
        kernel = self.settings.worker_kernel
        if kernel == "gpu":
            from renderer.wavefront import gpu_missing

            missing = gpu_missing()
            if missing is not None:
                # LUCENT_WORKER_KERNEL=gpu where no GPU is seen (``lucent worker`` refuses to
                # start so): each pass fails with this reason on its tile, and the node is
                # blocklisted for the job (pass_failed)
                log.error("worker_kernel gpu: %s", missing)
                kernel = "scalar"
        return warm_up_kernels(kernel)

    # --- heartbeat ------------------------------------------------------------------------------
    def start_heartbeat(self) -> None:
        self._beat = threading.Thread(target=self._beat_loop, name="lucent-heartbeat",
                                      daemon=True)
        self._beat.start()

    def stop_heartbeat(self) -> None:
        self._stop.set()
        try:
            self.store.remove_worker(self.worker_id)
        except Exception:  # Redis may be gone already at shutdown
            pass

    def beat(self) -> None:
        with self._lock:
            fields = {
                "host": socket.gethostname(),
                "pid": os.getpid(),
                "state": self.state,
                "current_task": self.current_task,
                "tiles_done": self.tiles_done,
                "paths_per_second": self.paths / self.render_seconds if self.render_seconds else 0,
                "started_at": self.started,
                "node": NODE,
                "tags": ",".join(self.settings.worker_tags),
                # (what its merge keeps, and its release: a farm upgraded worker by worker)
                "protocol": MERGE_PROTOCOL,
                "version": __version__,
                # (the service sizes a job's passes for the kernel the live workers render with)
                "kernel": self.settings.worker_kernel,
            }
        self.store.heartbeat(self.worker_id, fields, ttl=3 * self.settings.heartbeat_interval)

    def _beat_loop(self) -> None:
        while True:
            try:
                self.beat()
            except Exception:  # Redis down for a moment: try again next interval
                pass
            if self._stop.wait(self.settings.heartbeat_interval):
                return

    def set_task(self, task: str) -> None:
        with self._lock:
            self.state = "busy" if task else "idle"
            self.current_task = task

    def count_pass(self, paths: int, seconds: float) -> None:
        with self._lock:
            self.tiles_done += 1
            self.paths += paths
            self.render_seconds += seconds


STATE = WorkerState()
