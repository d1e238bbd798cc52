"""JIT options for every kernel, in one place (the PySDM/stumpy convention).

- ``cache=True``: compiled kernels are written to ``NUMBA_CACHE_DIR`` (set by ``renderer``), so a
  second process, a test run or a farm worker starts warm.
- ``fastmath=False``: the renderer depends on IEEE semantics (inf for parallel rays in slab tests,
  NaN checks on samples); fastmath would let LLVM assume neither exists.
- ``error_model="numpy"``: division by zero gives inf/NaN instead of raising, as the slab test and
  the dropped-sample accounting expect.
"""

from __future__ import annotations

from numba import njit

JIT_OPTIONS = {"cache": True, "nogil": True, "fastmath": False, "error_model": "numpy"}


def kernel(fn):
    """Compile ``fn`` as a serial numba kernel (or device function called from kernels)."""
    return njit(**JIT_OPTIONS)(fn)


def parallel_kernel(fn):
    """Compile ``fn`` as a numba kernel whose ``prange`` loops run on numba's thread pool."""
    return njit(parallel=True, **JIT_OPTIONS)(fn)
