"""Lucent's renderer: a numba path tracer for scene format v1.

The public entry points live in their modules (pbrt-like layout):

- ``renderer.scene``: ``load_scene``/``load_scene_file`` (schema and validation), ``compile_scene``;
- ``renderer.render``: ``render_tile`` (the farm's unit of work) and ``render``;
- ``renderer.film``: ``SampleBuffer`` and image files.

Importing this package only fixes where numba keeps its compiled kernels (see ``_cache_dir``); no
kernel is compiled until it is first called.
"""

from __future__ import annotations

import functools
import hashlib
import os
import sys
from pathlib import Path

__version__ = "0.1.0"


@functools.cache
def source_digest() -> str:
    """A hash of every renderer source file (16 hex digits): one per renderer version. Computed
    once a process, when the package is imported (``_cache_dir``), so the warm marker
    (``warm_marker``) names the version whose folder numba uses."""
    root = Path(__file__).parent
    digest = hashlib.sha1()
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def warm_marker() -> Path:
    """The file a warm-up leaves in numba's cache folder once it has compiled (or loaded) every
    kernel there (``worker.runtime.warm_up_kernels``), named by the renderer version (a folder
    set with ``NUMBA_CACHE_DIR`` is not keyed by it, the default one is: ``_cache_dir``)."""
    return Path(os.environ["NUMBA_CACHE_DIR"]) / f"lucent-warm-{source_digest()}"


def _cache_dir() -> str:
    """A numba cache folder keyed by the renderer's source.

    numba's ``cache=True`` checks only the timestamp of the file that holds the kernel, not of the
    files whose functions it inlines, so a changed ``sampling.py`` could leave a stale kernel in the
    cache. Keying the folder by a hash of every renderer source file makes that impossible.
    """
    base = os.environ.get("LUCENT_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "lucent"
    )
    return os.path.join(base, "numba", source_digest())


# numba reads its configuration when it is imported. A program that imported numba before this
# package (a benchmark with its own kernels, a test) would otherwise cache the renderer's kernels
# in __pycache__ beside the sources, where only timestamps guard them: numba's setting is mended
# too (it is read when a kernel with cache=True is defined, which is after this).
if "NUMBA_CACHE_DIR" not in os.environ:
    os.environ["NUMBA_CACHE_DIR"] = _cache_dir()
    if "numba.core.config" in sys.modules:
        sys.modules["numba.core.config"].CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]


def _wide_vectors() -> None:
    """On a CPU with AVX-512, let LLVM fill 512-bit vectors.

    LLVM tunes for Intel's AVX-512 server CPUs with ``prefer-256-bit`` (seen on Emerald
    Rapids): its loop vectorizer then uses half of each AVX-512 register. The packet kernel's 16
    float32 lanes (``renderer.packet``) fit one 512-bit register: with the preference lifted it drew
    7.60 / 6.74 M paths/s on the Cornell box against 5.98 / 5.15 (Xeon, Emerald Rapids, 2 cores,
    two rounds alternated, docs/performance.md "The packet kernel"), while the scalar kernel's
    scenes moved within the machine's spread. AMD's Zen 4 carries no such preference: nothing
    changes there. A ``NUMBA_CPU_FEATURES`` already set is left as it is (set it to the host's
    features to keep LLVM's preference). Numba keys its cache by the features, so a cache
    compiled under the other setting is not reused, never wrongly loaded."""
    if "NUMBA_CPU_FEATURES" in os.environ:
        return
    from llvmlite import binding

    features = binding.get_host_cpu_features().flatten()
    if "+avx512f" not in features.split(","):
        return
    os.environ["NUMBA_CPU_FEATURES"] = features + ",-prefer-256-bit"
    if "numba.core.config" in sys.modules:
        sys.modules["numba.core.config"].CPU_FEATURES = os.environ["NUMBA_CPU_FEATURES"]


_wide_vectors()
