"""The supervisor of ``lucent up``: a child that exits is reaped, reported and started again after
a delay that doubles with each exit in a row. Driven with the clock given (``check(now=...)``) on
real processes, so nothing here depends on how fast the machine is."""

from __future__ import annotations

import signal
import subprocess
import sys

from services.launcher import Backoff, Child, Supervisor


def test_backoff_doubles_to_its_cap_and_starts_again_after_a_healthy_run():
    b = Backoff(base=0.5, cap=4.0, healthy=60.0)
    assert [b.delay(1.0) for _ in range(6)] == [0.5, 1.0, 2.0, 4.0, 4.0, 4.0]
    assert b.delay(60.0) == 0.5  # it had run a minute: a new failure, not the same crash loop
    assert b.delay(0.1) == 1.0


def _sleeper() -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])


def test_a_killed_child_is_reaped_reported_and_started_again_with_backoff():
    said: list[str] = []
    child = Child("the sleeper", _sleeper)
    supervisor = Supervisor([child], say=said.append)  # not started: checked by hand
    child.run()
    try:
        t0 = child.started_at
        supervisor.check(child, now=t0 + 5)
        assert said == [] and child.restarts == 0  # alive: nothing to do
        first = child.proc
        first.send_signal(signal.SIGKILL)
        first.wait()
        supervisor.check(child, now=t0 + 10)  # reaped (returncode read), restart scheduled
        assert said == ["lucent up: the sleeper killed by SIGKILL after 10 s; starting it again "
                        "in 0.5 s"]
        assert child.restart_at == t0 + 10.5
        supervisor.check(child, now=t0 + 10.4)
        assert child.proc is first  # not yet
        supervisor.check(child, now=t0 + 10.5)
        second = child.proc
        assert second is not first and second.poll() is None
        assert child.restarts == 1 and said[-1].startswith("lucent up: the sleeper started again")
        # Exiting again at once: the next delay is twice as long.
        second.send_signal(signal.SIGTERM)
        second.wait()
        supervisor.check(child, now=child.started_at + 1)
        assert said[-1].endswith("killed by SIGTERM after 1 s; starting it again in 1 s")
    finally:
        if child.proc is not None and child.proc.poll() is None:
            child.proc.kill()
            child.proc.wait()


def test_a_child_that_fails_to_start_is_tried_again_later():
    said: list[str] = []
    attempts: list[int] = []

    def failing() -> subprocess.Popen:
        attempts.append(1)
        raise RuntimeError("redis-server did not start (exit 1)")

    child = Child("redis-server", failing, restart_at=0.0)
    supervisor = Supervisor([child], say=said.append)
    supervisor.check(child, now=1.0)
    assert attempts == [1] and child.restarts == 0
    assert said == ["lucent up: could not start redis-server: redis-server did not start "
                    "(exit 1); trying again in 0.5 s"]
    assert child.restart_at is not None
