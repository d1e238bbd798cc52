"""The worker app of the fault tests: ``celery -A faulty_worker worker`` with ``tests/farm`` on
``PYTHONPATH``. It is ``worker.celery_app``'s app with one ``(tile, pass)`` made to misbehave,
chosen by ``LUCENT_TEST_FAULT=<tile>:<pass>:<mode>`` in this worker's environment only (``*:*``:
every pass of every job, a node that fails all it is given). Neither
the service nor the production worker imports this module or reads that variable, so no request
can trigger a fault.

=========  ===========================================================================
mode       what the pass does
=========  ===========================================================================
``sleep``  its first try sleeps in Python: a hang that the soft time limit interrupts
``hang``   its first try blocks SIGUSR1 (Celery's soft-limit signal) and sleeps: like a
           numba kernel that never returns to Python, only the hard limit (SIGKILL) ends it
``raise``  every try raises: a tracer bug (the task's own retries, bounded)
``segv``   every try kills its process with SIGSEGV: a tracer crash (redeliveries, bounded)
=========  ===========================================================================
"""

from __future__ import annotations

import os
import signal
import time

from worker import tasks
from worker.celery_app import app

__all__ = ["app"]

_render_and_merge = tasks._render_and_merge


def _faulty_render_and_merge(state, meta, tile: int, pass_index: int, t_task: float,
                             tally: dict[str, float]) -> str:
    spec = os.environ.get("LUCENT_TEST_FAULT", "")
    if spec:
        fault_tile, fault_pass, mode = spec.split(":")
        if (fault_tile, fault_pass) == ("*", "*") or \
                (int(fault_tile), int(fault_pass)) == (tile, pass_index):
            store = state.store
            tries = int(store.r.hget(store.k("job", meta.id, "attempts"),
                                     f"{tile}:{pass_index}") or 0)
            if mode == "sleep" and tries == 1:
                time.sleep(3600)
            elif mode == "hang" and tries == 1:
                signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGUSR1})
                time.sleep(3600)
            elif mode == "raise":
                raise RuntimeError("the tracer failed (test fault)")
            elif mode == "segv":
                os.kill(os.getpid(), signal.SIGSEGV)
    return _render_and_merge(state, meta, tile, pass_index, t_task, tally)


# Patched in the parent before Celery forks its pool: every pool process inherits it.
tasks._render_and_merge = _faulty_render_and_merge
