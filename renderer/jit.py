"""JIT options for every kernel, in one place (the PySDM/stumpy convention).

- ``cache=True``: compiled kernels are written to ``NUMBA_CACHE_DIR`` (set by ``renderer``), so a
  second process, a test run or a farm worker starts warm.
- ``fastmath=False``: the renderer depends on IEEE semantics (inf for parallel rays in slab tests,
  NaN checks on samples); fastmath would let LLVM assume neither exists.
- ``error_model="numpy"``: division by zero gives inf/NaN instead of raising, as the slab test and
  the dropped-sample accounting expect.
- ``_nrt=False`` for the serial kernels (every device function of the tracer): numba's runtime
  reference-counts every array it takes out of the ``SceneArrays`` tuple, an atomic increment and
  decrement per access, hundreds of them in ``trace_path``. The kernels only borrow the arrays
  their caller owns, so they run without the runtime: the render is bit-identical and 1.5x faster
  (docs/performance.md, "Where the time goes"). Such a kernel cannot allocate an array (numba
  refuses to compile it) and must not return one (its caller would release a reference it never
  took: tests/renderer/test_jit.py checks every compiled signature). A serial kernel that
  allocates is an ``alloc_kernel``; the parallel kernels (the CPU wavefront stages) keep the
  runtime. The scalar kernel's rows, and the AOV pass's, run on threads of the host
  (``run_chunks``), whose stacks and scratch the host allocates.
- inlining (``inline_kernel``) for the device functions a call would pass the whole ``SceneArrays``
  tuple or seven of its arrays to: numba passes an array as ~7 scalars, so a call to
  ``surface_shadow`` took 186 arguments, one to ``intersect_closest`` 71. Inlining ``trace_path``
  into the row kernel (``render_rows``), ``transmittance`` and ``surface_shadow`` into it, and the
  BVH's ``intersect_closest`` and ``occluded`` made the Cornell box 1.875 s -> 1.54 s (2.62 -> 3.19
  M paths/s), images bit-identical; the price is compile time (cold cache 16 s -> 31 s).
  ``sample_light`` (55 scalar arguments, 3 call sites) and ``intersect_prim`` (9 sites in the
  traversal) followed once the slab test had lost its branches: +14 % and +7 % on the Cornell box in
  alternating A/B runs (an earlier, single-run try had seen nothing through the noise); cold compile
  40 s -> 52 s on that machine. The calls left: ``objdump -dr`` on the objects ``python -m
  bench.profile_kernel --keep DIR`` writes. Sites off the hot path call instead of inlining
  (``transmittance_by_crossing``, which only tree scenes use, and diffuse_entry's separate shadow
  ray, ``surface_shadow_call``): each inlined copy of a ray query adds compile time, and these two
  took the cold compile from 113 s to 67 s (docs/performance.md, "Start-up").
- ``inline_kernel`` inlines in LLVM, not in numba's IR: numba's ``forceinline`` marks the compiled
  function ``alwaysinline``, so it is typed and compiled once, for the plain types of its
  arguments (``_unliteral_calls``), and LLVM inlines its machine-level body at every call site,
  where the constants a caller passes fold as before. numba's own ``inline="always"`` inlines the
  callee's IR before typing, so every site typed and lowered its own copy (and numba's inliner
  deep-copied each copy twice): a cold compile took 65.5 s that way and 43.3 s now, in the same
  minutes, with the BSDFs inlined as well (``python -m bench.compile_passes``), and the renders
  are bit-identical (docs/performance.md, "Inlined by LLVM").
- ``kernel`` and ``alloc_kernel`` say ``forceinline=False``: numba lets a function that is
  compiled while an ``alwaysinline`` caller is typed inherit the flag, and a kernel meant to stay
  a call (``transmittance_by_crossing``) would be inlined at every site.
- ``draw`` stays a plain ``kernel``, compiled for each constant ``k`` it is called with (8
  signatures): unliteralled and inlined, the renders were 6–14 % slower. A literal can also be
  transient: ``trace_path``'s ``dim = 2`` was typed ``Literal[int](2)`` on type inference's first
  pass and int64 once the loop's ``dim +=`` reached it, so every ``draw`` compiled twice, and its
  literal copies were thrown away; ``dim = np.int64(2)`` took a cold compile from 46.9 s to
  35–38 s.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, wait

from numba import njit
from numba.core import cgutils, types
from numba.extending import intrinsic, overload

JIT_OPTIONS = {"cache": True, "nogil": True, "fastmath": False, "error_model": "numpy"}


def _unliteral_calls(dispatcher):
    """Make jitted callers compile ``dispatcher`` for the plain types of their arguments, not once
    for each constant they pass (numba types a constant argument as a literal: ``Literal[int](3)``,
    ``Literal[bool](False)``). Calls from Python are typed from values, never as literals.
    Under ``NUMBA_DISABLE_JIT`` (the CUDA simulator's tests run the stages as Python) ``njit``
    returns the function itself, and there is nothing to type."""
    if not hasattr(dispatcher, "get_call_template"):
        return dispatcher
    template = dispatcher.get_call_template

    def get_call_template(args, kws):
        return template(tuple(types.unliteral(a) for a in args),
                        {k: types.unliteral(v) for k, v in kws.items()})

    dispatcher.get_call_template = get_call_template
    return dispatcher


def kernel(fn):
    """Compile ``fn`` as a serial numba kernel (or device function called from kernels) that runs
    without numba's runtime: it takes arrays, never allocates or returns one."""
    return njit(_nrt=False, forceinline=False, **JIT_OPTIONS)(fn)


def parallel_kernel(fn):
    """Compile ``fn`` as a numba kernel whose ``prange`` loops run on numba's thread pool. It
    links in and optimizes again the whole code it calls (a cold compile's price, see
    ``run_chunks``), and hands work to its threads in ~10 us where ``run_chunks`` takes 50-100:
    the CPU wavefront stages, called thousands of times a frame, stay parallel kernels."""
    return njit(parallel=True, **JIT_OPTIONS)(fn)


# This process's threads for run_chunks: (pid, pool); a forked child makes its own
_pool: tuple[int, ThreadPoolExecutor] | None = None
_pool_lock = threading.Lock()


def _threads(n: int) -> ThreadPoolExecutor:
    global _pool
    with _pool_lock:
        if _pool is None or _pool[0] != os.getpid() or _pool[1]._max_workers < n:
            if _pool is not None and _pool[0] == os.getpid():
                _pool[1].shutdown(wait=False)
            _pool = (os.getpid(), ThreadPoolExecutor(n, thread_name_prefix="lucent-render"))
        return _pool[1]


def run_chunks(fn: Callable[[int], None], n: int) -> None:
    """Run ``fn(0)``, …, ``fn(n - 1)`` at once: ``fn(0)`` in the calling thread, the others on a
    pool of this process's threads, for a serial kernel that releases the GIL (``nogil``) run
    on n cores. Returns when all have ended; raises the first error. The pool is made again in a
    forked child (a prefork worker), whose copy of the parent's has no threads."""
    if n <= 1:
        if n == 1:
            fn(0)
        return
    futures = [_threads(n - 1).submit(fn, c) for c in range(1, n)]
    try:
        fn(0)
    finally:
        wait(futures)  # the others write into the caller's arrays: never return before them
    for future in futures:
        future.result()


@intrinsic
def _fetch_add(typingctx, counter, value):
    """LLVM's ``atomicrmw add`` on ``counter[0]`` (an int64 array): its value before the add."""
    sig = types.int64(counter, value)

    def codegen(context, builder, signature, args):
        ary, val = args
        aryty = signature.args[0]
        array = context.make_array(aryty)(context, builder, ary)
        ptr = cgutils.get_item_pointer(context, builder, aryty, array,
                                       [context.get_constant(types.intp, 0)])
        val = context.cast(builder, val, signature.args[1], types.int64)
        return builder.atomic_rmw("add", ptr, val, "seq_cst")

    return sig, codegen


_claim_lock = threading.Lock()


def claim_row(counter) -> int:
    """The next row of a pass for the thread that asks: ``counter[0]`` (int64), then one more,
    in one atomic step, so that the threads of a pass take its rows in turn as each finishes
    one (``run_chunks``' kernels), rather than each a fixed share that may hold the costly part
    of the frame. In compiled code an atomic add (``_fetch_add``); as Python (under
    ``NUMBA_DISABLE_JIT``, the CUDA simulator's tests) the same under a lock."""
    with _claim_lock:
        row = int(counter[0])
        counter[0] = row + 1
    return row


@overload(claim_row, jit_options={"cache": True})
def _claim_row_compiled(counter):
    def impl(counter):
        return _fetch_add(counter, 1)

    return impl


def alloc_kernel(fn):
    """Compile ``fn`` as a serial kernel that allocates arrays (needs numba's runtime)."""
    return njit(forceinline=False, **JIT_OPTIONS)(fn)


def inline_kernel(fn):
    """A ``kernel`` that LLVM inlines into every caller (``alwaysinline``, numba's
    ``forceinline``), compiled once for the plain types of its arguments: for device functions
    that take the whole ``SceneArrays`` tuple, which a call passes as ~180 scalar arguments."""
    return _unliteral_calls(njit(forceinline=True, _nrt=False, **JIT_OPTIONS)(fn))


def block(fn):
    """A block of its caller's code, given a name and a file of its own for the reader: numba
    inlines its IR at the call site before typing (``inline="always"``), so it is typed and
    compiled as part of its caller and has no compile of its own. For functions called from one
    or two sites (each site types its own copy): the subsurface methods' steps and the path's
    next-event estimates. As ``inline_kernel``s, each was also compiled and optimized alone, which
    added ~4 s to a 23 s cold compile (``python -m bench.compile_passes``)."""
    return njit(inline="always", _nrt=False, **JIT_OPTIONS)(fn)

