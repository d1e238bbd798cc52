"""Faster ``inline="always"``: numba's inliner without its two deep copies of a fresh callee.

The tracer inlines its device functions into ``render_row`` (``renderer/jit.py``,
``inline_kernel``), and a cold compile spent most of its time there: a profile of ``lucent render
--spp 1`` on an empty cache had 72 of 163 s (under cProfile) in ``copy.deepcopy``, called from
numba's ``InlineWorker.inline_ir``. For each call site numba builds the callee's IR afresh
(``inline_function`` runs the untyped pipeline on it), then copies it twice: once to mutate, once
to keep an unmutated original, which ``InlineInlinables`` throws away. Each copy deep-copies block
by block, each block with a memo of its own, so the function's whole scope (every variable) is
copied once per block: quadratic in the callee's size, and the largest callees are the ones
already inlined into.

Nothing else holds the IR ``inline_function`` has just built, so it can be inlined as it is. This
module replaces ``InlineWorker.inline_function`` by the same three steps, with the copies turned
into the identity while ``inline_ir`` runs (``inline_closurecall`` calls ``copy.deepcopy`` in those
two copies and nowhere else). ``inline_ir`` called by other paths (numba's ``@overload`` inlining,
which hands it a cached IR) keeps its copies. The machine code is the same: the kernels' LLVM IR is
compared with and without it (tests/renderer/test_numba_inline.py), and images are bit-identical.
Measured: cold compile of ``lucent render --spp 1`` 78 s -> 58 s, of a worker 87 s -> 60 s
(docs/performance.md, "Start-up"). The maintainers' threads: numba/numba#8989 and #9204 (the
extra copy, the per-block copies), NVIDIA/numba-cuda#689 (the same change for CUDA).

Applied only where numba's source has the shape this module relies on (``_shape_is_known``: the
two steps of ``inline_function``, and ``copy.deepcopy`` in inline_closurecall only in
``inline_ir``'s copies), read from the installed numba at import; numba 0.68.1 has it.
``LUCENT_NUMBA_FAST_INLINE=0`` leaves numba as it is.
"""

from __future__ import annotations

import copy
import inspect
import os
import re
import types

from numba.core import inline_closurecall

_ORIGINAL = inline_closurecall.InlineWorker.inline_function
_IDENTITY = types.SimpleNamespace(deepcopy=lambda x, memo=None: x)


def _shape_is_known() -> bool:
    """True when the installed numba's inliner is the one ``inline_function`` reproduces."""
    try:
        function = inspect.getsource(_ORIGINAL)
        inline_ir = inspect.getsource(inline_closurecall.InlineWorker.inline_ir)
        module = inspect.getsource(inline_closurecall)
    except (OSError, TypeError):
        return False
    return (getattr(inline_closurecall, "copy", None) is copy
            and "callee_ir = self.run_untyped_passes(function)" in function
            and "return self.inline_ir(caller_ir, block, i, callee_ir, freevars" in function
            and "copy.deepcopy(the_ir.blocks[block_label])" in inline_ir
            and len(re.findall(r"\bcopy\.", module)) == 1)


def inline_function(self, caller_ir, block, i, function, arg_typs=None):
    """numba's ``InlineWorker.inline_function``, with the callee IR it has just built inlined
    without copying it."""
    callee_ir = self.run_untyped_passes(function)
    freevars = function.__code__.co_freevars
    # numba compiles under a global lock, so no other inlining runs while the name is swapped
    inline_closurecall.copy = _IDENTITY
    try:
        return self.inline_ir(caller_ir, block, i, callee_ir, freevars, arg_typs=arg_typs)
    finally:
        inline_closurecall.copy = copy


def install() -> bool:
    """Use the copy-free ``inline_function`` where it applies; True when it is in use."""
    if os.environ.get("LUCENT_NUMBA_FAST_INLINE", "1") == "0":
        inline_closurecall.InlineWorker.inline_function = _ORIGINAL
        return False
    if not _shape_is_known():
        return False
    inline_closurecall.InlineWorker.inline_function = inline_function
    return True


INSTALLED = install()
