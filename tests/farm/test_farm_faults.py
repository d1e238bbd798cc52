"""Faults, with nothing lost: each test ends with its job done, every pixel holding exactly its
``spp`` samples, every pass merged once and the image equal to the local render — or, where the
fault is one the farm cannot survive, with the job failed or reported lost, never hanging.

Each test has its own embedded Redis (some restart it, one puts a proxy in front of it) and its
own worker nodes, started with short time limits so that redeliveries come within seconds:
``visibility_timeout`` 8 s (hard limit 6 s, soft 4 s; a pass here takes milliseconds), stall
time 8 s, heartbeats every 0.25 s. ``faulty_worker`` is the worker app with a test-only fault in
one pass.
"""

from __future__ import annotations

import base64
import contextlib
import copy
import io
import json
import os
import random
import re
import signal
import socket
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import redis
from fastapi.testclient import TestClient

from renderer.render import render
from services.api.main import create_app
from services.client import Client
from services.farm.merge import StallRule, assemble, requeue_stalled
from services.farm.planner import Plan, celery_priority
from services.farm.queue import TASK, celery_client
from services.farm.records import LOST_AFTER
from services.farm.settings import Settings
from services.farm.store import JobStore
from services.launcher import EmbeddedRedis, free_port, terminate, worker_command, worker_env

psutil = pytest.importorskip("psutil")

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
VISIBILITY_TIMEOUT = 8.0
STALL_TIMEOUT = 8.0
# The same short limits for the workers (their environment) and the API (its Settings).
TIMINGS = {"visibility_timeout": VISIBILITY_TIMEOUT, "task_soft_time_limit": 4.0,
           "task_time_limit": 6.0, "stall_timeout": STALL_TIMEOUT}
FAULT_ENV = {
    **{f"LUCENT_{name.upper()}": str(value) for name, value in TIMINGS.items()},
    "LUCENT_HEARTBEAT_INTERVAL": "0.25",
    "LUCENT_API_TOKEN": "",
}
TIMEOUT = 120.0


def _until(predicate, timeout: float, what: str, interval: float = 0.05):
    """``predicate()`` until truthy; a Redis that is down for a moment counts as not yet."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            value = predicate()
        except redis.RedisError:
            value = None
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(interval)


class Nodes:
    """Worker nodes (``celery worker`` processes) on one Redis and key prefix."""

    def __init__(self, redis_url: str, prefix: str, log_dir: Path):
        self.redis_url, self.prefix, self.log_dir = redis_url, prefix, log_dir
        self.procs: list[subprocess.Popen] = []

    def start(self, concurrency: int = 2, redis_url: str | None = None, app: str | None = None,
              **env: str) -> subprocess.Popen:
        cmd = worker_command(concurrency, name=f"n{len(self.procs)}-{self.prefix}@%h")
        extra = {**FAULT_ENV, "LUCENT_KEY_PREFIX": self.prefix, **env}
        if app:  # the test-only app in tests/farm
            cmd[cmd.index("worker.celery_app")] = app
            extra["PYTHONPATH"] = os.pathsep.join([str(HERE), str(ROOT)])
        log = open(self.log_dir / f"node{len(self.procs)}.log", "w")  # noqa: SIM115
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT,
                                env=worker_env(redis_url or self.redis_url, 1, extra))
        log.close()
        self.procs.append(proc)
        return proc

    def pool(self, proc: subprocess.Popen) -> list[int]:
        return [c.pid for c in psutil.Process(proc.pid).children()]

    def _wait_beating(self, store: JobStore, proc: subprocess.Popen, n: int,
                      states: tuple[str, ...], what: str, interval: float) -> list[int]:
        """Until ``n`` pool processes of ``proc`` beat in one of ``states``; the pids that do."""
        def beating():
            assert proc.poll() is None, self.logs()
            pids = {int(w["pid"]) for w in store.workers() if w.get("state") in states}
            found = [p for p in self.pool(proc) if p in pids]
            return found if len(found) >= n else None
        return _until(beating, 240.0, what, interval=interval)

    def wait_warm(self, store: JobStore, proc: subprocess.Popen, n: int) -> list[int]:
        """Until ``n`` pool processes of ``proc`` beat as idle or busy; their pids."""
        return self._wait_beating(store, proc, n, ("idle", "busy"), "warm worker processes", 0.1)

    def wait_busy(self, store: JobStore, proc: subprocess.Popen) -> list[int]:
        """Until a pool process of ``proc`` beats as busy (a task in hand); the pids that do."""
        return self._wait_beating(store, proc, 1, ("busy",), "a busy worker process", 0.01)

    def kill(self, proc: subprocess.Popen) -> None:
        """SIGKILL the node and its pool at once: a machine losing power."""
        children = self.pool(proc)
        proc.kill()
        for pid in children:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        proc.wait()

    def logs(self) -> str:
        return "\n".join(p.read_text()[-2000:] for p in sorted(self.log_dir.glob("node*.log")))

    def stop(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                self.kill(proc)


@pytest.fixture
def prefix() -> str:
    return f"lucent-fault-{uuid.uuid4().hex[:8]}"


@pytest.fixture
def own_redis(tmp_path: Path) -> Iterator[EmbeddedRedis]:
    server = EmbeddedRedis().start()
    yield server
    server.stop()


@pytest.fixture
def nodes(own_redis: EmbeddedRedis, prefix: str, tmp_path: Path) -> Iterator[Nodes]:
    n = Nodes(own_redis.url, prefix, tmp_path)
    yield n
    n.stop()


def _api(redis_url: str, prefix: str) -> TestClient:
    """The API on that Redis: its sweeper merges leftovers, finishes jobs and re-queues the
    passes of jobs stalled for ``STALL_TIMEOUT`` every 0.2 s. Done jobs keep their accumulations
    in Redis (``archive_done`` off): ``_assert_nothing_lost`` counts every pixel's samples."""
    return TestClient(create_app(Settings(redis_url=redis_url, key_prefix=prefix,
                                          sweep_interval=0.2, api_token=None,
                                          archive_done=False, **TIMINGS)))


def _scene(cornell: dict, width: int, height: int, spp: int) -> dict:
    scene = copy.deepcopy(cornell)
    scene["film"] = {"width": width, "height": height}
    scene["render"]["spp"] = spp
    return scene


def _submit(api: TestClient, scene: dict, tile_size: int, spp_per_pass: int) -> str:
    # Equal passes: the faults below are timed by the share of a job's many short tasks merged
    # (growing passes would make the jobs a few long tasks).
    r = api.post("/api/jobs", json={"scene": scene, "tile_size": tile_size,
                                    "spp_per_pass": spp_per_pass,
                                    "max_spp_per_pass": spp_per_pass})
    assert r.status_code == 201, r.text
    return r.json()["id"]


def _finished(store: JobStore, job_id: str, timeout: float = TIMEOUT) -> str:
    try:
        return _until(lambda: (s := store.get_status(job_id)) in ("done", "failed", "cancelled")
                      and s, timeout, f"job {job_id} to finish", interval=0.1)
    except AssertionError as err:  # say what it waits for
        raise AssertionError(f"{err}: {_stuck(store, job_id)}") from None


def _assert_nothing_lost(api: TestClient, store: JobStore, job_id: str, scene: dict) -> None:
    """Done, each pass merged once, every pixel exactly spp samples, the local render's image."""
    job = api.get(f"/api/jobs/{job_id}").json()
    assert job["status"] == "done", job
    assert job["tasks_merged"] == job["tasks_total"]
    assert store.r.scard(store.k("job", job_id, "merged")) == job["tasks_total"]
    assert {t["state"] for t in job["tile_states"]} == {"done"}
    frame, _ = assemble(store, job_id)
    assert (frame.count + frame.dropped == scene["render"]["spp"]).all()
    _until(lambda: store.r.scard(store.k("pending")) == 0, 10, "no pass buffer left")
    image = np.load(io.BytesIO(api.get(f"/api/jobs/{job_id}/image.npy").content))
    np.testing.assert_allclose(image, render(scene), rtol=1e-5, atol=1e-7)


def _stuck(store: JobStore, job_id: str) -> str:
    """What a job that does not finish is waiting for: its passes not merged, their tries, and
    the broker's queue and unacknowledged messages."""
    meta = store.get_job(job_id)
    merged = {m.decode() for m in store.r.smembers(store.k("job", job_id, "merged"))}
    missing = [f"{t}:{p}" for t, p in meta.plan.order() if f"{t}:{p}" not in merged]
    tries = _attempts(store, job_id)
    queued = {key: n for key in ["celery"] + [f"celery:{level}" for level in range(1, 10)]
              if (n := store.r.llen(key))}
    return (f"{meta.status}, not merged: {[(m, tries.get(m)) for m in missing]}, "
            f"queued {queued}, unacked {store.r.hlen('unacked')}")


def _attempts(store: JobStore, job_id: str) -> dict[str, int]:
    h = store.r.hgetall(store.k("job", job_id, "attempts"))
    return {k.decode(): int(v) for k, v in h.items()}


def _queue_keys(priority: int) -> list[str]:
    """Celery's Redis list that holds the messages of a job of this priority (kombu keeps one
    list per level, named ``celery``, ``celery:1``, ... with ``sep`` ``:``)."""
    level = celery_priority(priority)
    return ["celery" if level == 0 else f"celery:{level}"]


def _queued_passes(store: JobStore, priority: int) -> dict[tuple[str, int, int], bytes]:
    """The ``render_pass`` messages waiting at a job priority's level: (job, tile, pass) -> the
    raw message (Celery protocol 2: the body is base64 JSON ``[args, kwargs, embed]``)."""
    out = {}
    for key in _queue_keys(priority):
        for raw in store.r.lrange(key, 0, -1):
            message = json.loads(raw)
            assert message["headers"]["task"] == TASK
            args = json.loads(base64.b64decode(message["body"]))[0]
            out[tuple(args)] = raw
    return out


# --- 0. a message lost by the broker: the sweeper's stall rule -----------------------------------
# A kombu consumer that dies as its node would if SIGKILLed between BRPOP and the unacked record.
_DIE_IN_APPEND = """
import os, signal, sys
from kombu import Connection, Queue
from kombu.transport import redis as transport

def append(qos, message, delivery_tag):  # where kombu writes the message to ``unacked``
    os.kill(os.getpid(), signal.SIGKILL)

transport.QoS.append = append
with Connection(sys.argv[1]) as conn:
    with conn.Consumer(Queue("lost"), callbacks=[lambda body, message: message.ack()]):
        conn.drain_events(timeout=30)
"""


def test_kombu_loses_a_message_popped_before_its_unacked_record(own_redis):
    """Why the stall rule exists, shown with kombu itself: a consumer killed after ``BRPOP`` took
    the message and before ``QoS.append`` recorded it leaves it in no queue and in no unacked
    hash, so ``restore_visible`` (the visibility timeout) can never bring it back."""
    from kombu import Connection

    with Connection(own_redis.url) as conn:
        conn.SimpleQueue("lost").put({"tile": 0})
        client = redis.Redis.from_url(own_redis.url)
        assert client.llen("lost") == 1
        proc = subprocess.run([sys.executable, "-c", _DIE_IN_APPEND, own_redis.url], cwd=ROOT,
                              timeout=60, capture_output=True)
        assert proc.returncode == -signal.SIGKILL, proc.stderr.decode()
        assert client.llen("lost") == 0
        assert client.hlen("unacked") == 0 and client.zcard("unacked_index") == 0
        client.close()


def test_settings_nest_the_stall_time() -> None:
    """A running pass (up to the hard limit) is not a stall; nor can a sweep miss one."""
    Settings(task_time_limit=6, stall_timeout=6.5, visibility_timeout=8, task_soft_time_limit=4)
    with pytest.raises(ValueError, match="task_time_limit < stall_timeout"):
        Settings(task_time_limit=6, stall_timeout=6, visibility_timeout=8,
                 task_soft_time_limit=4)
    with pytest.raises(ValueError, match="sweep_interval < stall_timeout"):
        Settings(sweep_interval=500)
    assert Settings().stall_timeout == Settings().task_time_limit + 60


def test_stall_rule_requeues_then_fails_the_job(own_redis, prefix):
    """``requeue_stalled`` on a real Redis and Celery client, no workers, clock given: a job is
    re-queued only once idle for the stall time with nothing of its level or above queued; only
    its unmerged passes, as real ``render_pass`` messages, without spending a try; a pass
    starting restarts the count; past ``max_stall_requeues`` stalls in a row the job fails with
    the reason."""
    settings = Settings(redis_url=own_redis.url, key_prefix=prefix, api_token=None,
                        max_stall_requeues=2, **TIMINGS)
    store = JobStore.from_url(own_redis.url, prefix)
    rule = StallRule(celery_client(settings), settings.stall_timeout,
                     settings.max_stall_requeues)
    plan = Plan(16, 16, 8, 8, 4)  # 4 tiles x 2 passes
    priority = 5
    store.create_job("j", "", priority, plan, "{}")
    step = STALL_TIMEOUT + 0.5
    # The clock given starts in the past, so that a pass started now (real time) is later.
    t0 = time.time() - 10 * step
    store.r.hset(store.job_key("j"), "created_at", t0)
    store.r.sadd(store.k("job", "j", "merged"), "0:0")  # one pass merged already
    todo = [tp for tp in plan.order() if tp != (0, 0)]

    def level_key(level: int) -> str:
        return "celery" if level == 0 else f"celery:{level}"

    # Idle for less than the stall time: nothing.
    assert requeue_stalled(store, rule, "j", now=t0 + STALL_TIMEOUT - 0.1) == []
    # Idle long enough, but a message of a higher priority (served first) waits: nothing.
    store.r.lpush(level_key(celery_priority(priority + 1)), b"other")
    assert requeue_stalled(store, rule, "j", now=t0 + step) == []
    store.r.delete(level_key(celery_priority(priority + 1)))
    # Lower-priority messages do not hold it back: its unmerged passes go out, in plan order.
    store.r.lpush(level_key(celery_priority(priority - 1)), b"other")
    assert requeue_stalled(store, rule, "j", now=t0 + step) == todo
    queued = _queued_passes(store, priority)
    assert sorted(queued) == sorted(("j", t, p) for t, p in todo)
    assert store.r.hget(store.job_key("j"), "stalls") == b"1"
    assert store.r.hlen(store.k("job", "j", "attempts")) == 0  # no try spent
    # Its messages waiting now: not stalled however long; lost again: the second stall.
    assert requeue_stalled(store, rule, "j", now=t0 + 3 * step) == []
    store.r.delete(*_queue_keys(priority))
    assert requeue_stalled(store, rule, "j", now=t0 + 1.5 * step) == []  # clock restarted
    assert requeue_stalled(store, rule, "j", now=t0 + 2 * step) == todo
    assert store.r.hget(store.job_key("j"), "stalls") == b"2"
    # A pass that starts is a sign of life: the next stall counts from 1 again.
    store.r.delete(*_queue_keys(priority))
    store.add_attempt("j", 1, 0)
    active = float(store.r.hget(store.job_key("j"), "active_at"))
    assert requeue_stalled(store, rule, "j", now=active + step) == todo
    assert store.r.hget(store.job_key("j"), "stalls") == b"1"
    # Lost every time: stalls 2, then the third in a row fails the job with the reason.
    store.r.delete(*_queue_keys(priority))
    assert requeue_stalled(store, rule, "j", now=active + 2 * step) == todo
    store.r.delete(*_queue_keys(priority))
    assert requeue_stalled(store, rule, "j", now=active + 3 * step) == []
    meta = store.get_job("j")
    assert meta.status == "failed"
    assert meta.error == (f"stalled: no pass started or merged for {STALL_TIMEOUT:g} s after 2 "
                          "re-queues of its unmerged passes")
    assert not _queued_passes(store, priority)
    assert requeue_stalled(store, rule, "j", now=active + 9 * step) == []  # failed: left alone
    store.r.close()


def test_a_job_no_live_worker_renders_stalls_sooner(own_redis, prefix):
    """The stall time of a job none of whose passes a live worker process holds is
    ``unheld_timeout``, not the full one (which waits out a running pass's time limit): nothing
    of it can be running, e.g. its last message sits in kombu's unacked hash after its worker
    lost Redis. A pass held by a worker whose heartbeat has expired does not count."""
    settings = Settings(redis_url=own_redis.url, key_prefix=prefix, api_token=None, **TIMINGS)
    store = JobStore.from_url(own_redis.url, prefix)
    rule = StallRule(celery_client(settings), STALL_TIMEOUT, 3, unheld_timeout=2.0)
    plan = Plan(16, 16, 8, 8, 4)  # 4 tiles x 2 passes
    store.create_job("u", "", 0, plan, "{}")
    store.r.hset(store.job_key("u"), "created_at", time.time() - 100)
    todo = plan.order()
    # A live worker holds one of its passes: only the full stall time counts.
    store.heartbeat("w1", {"state": "busy"}, ttl=600)
    store.add_attempt("u", 0, 0, holder="w1")
    assert store.job_held("u")
    active = float(store.r.hget(store.job_key("u"), "active_at"))
    assert requeue_stalled(store, rule, "u", now=active + 3) == []
    assert requeue_stalled(store, rule, "u", now=active + STALL_TIMEOUT + 0.1) == todo
    store.r.delete(*_queue_keys(0))
    since = active + STALL_TIMEOUT + 0.1
    # Its worker's heartbeat expired: the holding no longer counts.
    store.r.delete(store.k("worker", "w1"))
    assert not store.job_held("u")
    assert requeue_stalled(store, rule, "u", now=since + 1.9) == []
    assert requeue_stalled(store, rule, "u", now=since + 2.1) == todo
    store.r.delete(*_queue_keys(0))
    # Held by nobody (a pass of another job held does not count), and nothing queued.
    store.release_pass("w1")
    store.heartbeat("w2", {"state": "busy"}, ttl=600)
    store.create_job("other", "", 0, plan, "{}")
    store.add_attempt("other", 0, 0, holder="w2")
    assert not store.job_held("u")
    assert requeue_stalled(store, rule, "u", now=since + 4.3) == todo
    store.r.delete(*_queue_keys(0))
    assert requeue_stalled(store, rule, "u", now=since + 6.5) == []  # the 4th in a row fails it
    meta = store.get_job("u")
    assert meta.status == "failed" and meta.error.startswith(
        "stalled: no pass started or merged for 2 s after 3 re-queues"), meta.error
    store.r.close()


def test_a_target_job_queues_only_each_tiles_first_pass(own_redis, prefix, tiny_scene,
                                                        tmp_path):
    """Submitted through the API (no workers): a job with a target error puts pass 0 of each
    tile in the queue; cancelled, parked out of Redis and retried, it comes back with its
    target and queues each tile's first unmerged pass again, not every planned pass; the same
    job without a target puts every planned pass."""
    from tests.conftest import wait_until

    settings = Settings(redis_url=own_redis.url, key_prefix=prefix, api_token=None,
                        data_dir=tmp_path, park_after=0.0, sweep_interval=0.2, **TIMINGS)
    store = JobStore.from_url(own_redis.url, prefix)
    target = copy.deepcopy(tiny_scene)
    target["render"].update(spp=256, target_error=0.02)
    with TestClient(create_app(settings)) as api:
        job = api.post("/api/jobs", json={"scene": target, "tile_size": 8}).json()
        assert job["passes"] > 1
        heads = [(job["id"], t, 0) for t in range(job["tiles"])]
        assert sorted(_queued_passes(store, 0)) == heads
        store.r.delete(*_queue_keys(0))
        assert api.delete(f"/api/jobs/{job['id']}").json()["status"] == "cancelled"
        wait_until(lambda: store.get_status(job["id"]) is None, 30, "the job parked")
        r = api.post(f"/api/jobs/{job['id']}/retry")
        assert r.status_code == 200, r.text
        assert r.json()["target_error"] == 0.02
        assert sorted(_queued_passes(store, 0)) == heads
        store.r.delete(*_queue_keys(0))
        plain = copy.deepcopy(target)
        del plain["render"]["target_error"]
        job = api.post("/api/jobs", json={"scene": plain, "tile_size": 8}).json()
        assert len(_queued_passes(store, 0)) == job["tiles"] * job["passes"]


def _pilot_job(own_redis, prefix, job_id: str):
    """A job with a target error, two tiles of 16 px and passes of 8, whose tile 0 has ended
    its pilot and waits, converged, for the frames' estimate there, and whose tile 1 has merged
    its first look: (store, stall rule, priority, a maker of tile 1's rest of the pilot)."""
    from renderer.film.adaptive import FIRST_LOOK, PILOT
    from renderer.film.buffer import SampleBuffer

    settings = Settings(redis_url=own_redis.url, key_prefix=prefix, api_token=None, **TIMINGS)
    store = JobStore.from_url(own_redis.url, prefix)
    rule = StallRule(celery_client(settings), settings.stall_timeout,
                     settings.max_stall_requeues)
    plan = Plan(32, 16, 256, 16, 8)
    priority = 5
    store.create_job(job_id, "", priority, plan, "{}", target_error=0.02)
    rng = np.random.default_rng(3)

    def pass_buffer(tile: int, n: int) -> bytes:  # n noisy grey samples a pixel
        buf = SampleBuffer.empty(*plan.tile_rect(tile))
        x = rng.exponential(1.0, (n, 16, 16, 1))
        buf.sum[:], buf.sum_sq[:], buf.count[:] = x.sum(axis=0), (x * x).sum(axis=0), n
        return buf.to_bytes()

    for tile, p, n in ((0, 0, FIRST_LOOK), (0, 1, PILOT - FIRST_LOOK), (1, 0, FIRST_LOOK)):
        store.put_pass(job_id, tile, p, pass_buffer(tile, n), ttl=60)
        assert store.merge_pass_buffer(job_id, tile, p)
    store.set_tile_state(job_id, 0, "converged")  # (as its worker, finding nothing yet)
    return store, rule, priority, lambda: pass_buffer(1, PILOT - FIRST_LOOK)


def test_a_sweeper_merge_that_ends_the_frames_pilot_wakes_the_waiting_tiles(own_redis, prefix):
    """Tile 1's pass that ends the frame's pilot was rendered by a worker that died before
    merging it. The sweeper merges it and, as that worker would have, queues tile 1's next pass
    and tile 0's (``queue.continue_chain``, ``targets.wake_converged``), not at the job's end.
    Seen failing without the wake."""
    from services.farm.merge import sweep

    store, rule, priority, rest = _pilot_job(own_redis, prefix, "w")
    store.put_pass("w", 1, 1, rest(), ttl=60)  # left behind
    try:
        assert sweep(store, rule) == 1
        assert store.get_job("w").pilot_error is not None
        assert sorted(_queued_passes(store, priority)) == [("w", 0, 2), ("w", 1, 2)]
        assert store.tile_states("w")[0] == "queued"
    finally:
        store.r.delete(*_queue_keys(priority))
        store.close()


def test_a_worker_lost_after_the_merge_that_ends_the_frames_pilot_leaves_no_tile_waiting(
        own_redis, prefix):
    """Tile 1's worker merged the pass that ends the frame's pilot and died before queuing
    anything, its next pass or the waiting tile 0's. Once its heartbeat has expired the
    sweeper's ``requeue_lost`` queues both (``queue.continue_chain``), not at the job's end.
    Seen failing without the wake."""
    from services.farm.lost_workers import requeue_lost

    store, rule, priority, rest = _pilot_job(own_redis, prefix, "l")
    store.put_pass("l", 1, 1, rest(), ttl=60)
    assert store.merge_pass_buffer("l", 1, 1)  # (its merge, and then nothing)
    store.r.hset(store.k("holding"), mapping={"gone:1": "l 1 1 1"})
    try:
        assert store.get_job("l").pilot_error is not None
        assert sorted(requeue_lost(store, rule.celery)) == [("l", 1, 2)]
        assert sorted(_queued_passes(store, priority)) == [("l", 0, 2), ("l", 1, 2)]
        assert store.tile_states("l")[0] == "queued"
    finally:
        store.r.delete(*_queue_keys(priority))
        store.close()


def test_a_worker_lost_after_its_tiles_last_merge_leaves_the_job_settled(own_redis, prefix):
    """A job with a target error, two tiles of noiseless samples: tile 0 ended its pilot and
    waits, converged, at its pass 2; tile 1's worker merged its last pass and died before
    settling the job (``targets.settle_converged``). Once its heartbeat has expired the
    sweeper's ``requeue_lost`` settles it: tile 0 is asked again, finds the frame's estimate
    within the aim, and the job is done, not left to the stall rule. Seen failing without the
    settle."""
    from renderer.film.buffer import SampleBuffer
    from services.farm.lost_workers import requeue_lost

    settings = Settings(redis_url=own_redis.url, key_prefix=prefix, api_token=None, **TIMINGS)
    store = JobStore.from_url(own_redis.url, prefix)
    rule = StallRule(celery_client(settings), settings.stall_timeout,
                     settings.max_stall_requeues)
    plan = Plan(32, 16, 24, 16, 8)  # 2 tiles x 3 passes of 8
    store.create_job("s", "", 5, plan, "{}", target_error=0.02)

    def merge(tile: int, p: int, n: int) -> None:  # n samples a pixel of radiance 1
        buf = SampleBuffer.empty(*plan.tile_rect(tile))
        buf.sum[:], buf.sum_sq[:], buf.count[:] = n, n, n
        store.put_pass("s", tile, p, buf.to_bytes(), ttl=60)
        assert store.merge_pass_buffer("s", tile, p)

    for tile, p, n in ((0, 0, 4), (0, 1, 4), (1, 0, 4), (1, 1, 4), (1, 2, 16)):
        merge(tile, p, n)
    store.set_tile_state("s", 0, "converged")
    store.r.hset(store.k("holding"), mapping={"gone:1": "s 1 2 1"})
    try:
        assert store.get_job("s").status == "queued"  # (no worker marked it started)
        assert requeue_lost(store, rule.celery) == []
        assert store.get_job("s").status == "done"
    finally:
        store.close()


def test_a_target_job_requeues_and_sweeps_one_pass_a_tile(own_redis, prefix):
    """A job with a target error runs each tile's passes as a chain (each queues the next:
    ``planner.chain_heads``). So the stall rule sends each tile's first unmerged pass only, the
    sweeper that merges a pass its worker left behind queues the tile's next one, and a converged
    tile's later passes count as merged in one step, once."""
    from renderer.film.buffer import SampleBuffer
    from services.farm.merge import sweep

    settings = Settings(redis_url=own_redis.url, key_prefix=prefix, api_token=None, **TIMINGS)
    store = JobStore.from_url(own_redis.url, prefix)
    rule = StallRule(celery_client(settings), settings.stall_timeout,
                     settings.max_stall_requeues)
    plan = Plan(16, 16, 24, 8, 8)  # 4 tiles x 3 passes of 8
    priority = 5
    store.create_job("t", "", priority, plan, "{}", target_error=0.02)
    t0 = time.time() - 10 * STALL_TIMEOUT
    store.r.hset(store.job_key("t"), "created_at", t0)
    store.r.sadd(store.k("job", "t", "merged"), "0:0", "1:0", "1:1")
    sent = requeue_stalled(store, rule, "t", now=t0 + STALL_TIMEOUT + 0.5)
    assert sorted(sent) == [(0, 1), (1, 2), (2, 0), (3, 0)]
    assert sorted(_queued_passes(store, priority)) == [("t", t, p) for t, p in sorted(sent)]
    store.r.delete(*_queue_keys(priority))

    # A worker rendered tile 2's pass 0 and died before merging it: the sweeper merges it and
    # queues pass 1 of tile 2, as the worker would have.
    buf = SampleBuffer.empty(*plan.tile_rect(2))
    buf.sum[:] = 1.0
    buf.sum_sq[:] = 1.5
    buf.count[:] = 8
    store.put_pass("t", 2, 0, buf.to_bytes(), ttl=60)
    assert sweep(store, rule) == 1
    assert sorted(_queued_passes(store, priority)) == [("t", 2, 1)]
    assert sweep(store, rule) == 0  # merged once, queued once
    assert sorted(_queued_passes(store, priority)) == [("t", 2, 1)]

    # A worker process merged tile 1's pass 2 (its last) and tile 0's pass 1, then died holding
    # the latter: its heartbeat gone, the sweeper sends tile 0's pass 2 (it may never have been
    # queued); a merged last pass sends nothing.
    from services.farm.lost_workers import requeue_lost

    store.r.delete(*_queue_keys(priority))
    store.r.sadd(store.k("job", "t", "merged"), "0:1", "1:2")
    store.r.hset(store.k("holding"), mapping={"gone:1": "t 0 1 1", "gone:2": "t 1 2 1"})
    assert sorted(requeue_lost(store, rule.celery)) == [("t", 0, 2)]
    assert sorted(_queued_passes(store, priority)) == [("t", 0, 2)]

    # Tile 3 converged at its pass 1: passes 1 and 2 count as merged, the tile is done.
    merged_before = store.get_job("t").tasks_merged
    assert store.skip_passes("t", 3, 1, plan.n_passes) == 2
    assert store.skip_passes("t", 3, 1, plan.n_passes) == 0
    assert store.get_job("t").tasks_merged == merged_before + 2
    assert store.r.hget(store.k("job", "t", "tile_state"), "3") == b"done"
    assert store.r.sismember(store.k("job", "t", "merged"), "3:2")
    # Not for a job that has ended
    store.cancel_job("t")
    assert store.skip_passes("t", 0, 1, plan.n_passes) == 0


@pytest.mark.slow
def test_a_lost_message_is_sent_again_when_its_job_stalls(own_redis, nodes, prefix, cornell):
    """The loss a worker node SIGKILLed between kombu's BRPOP and its ``unacked`` record causes,
    made deterministic: the job is submitted before any worker runs and one of its messages is
    removed from Celery's queue by hand. A node renders the rest; then, nothing queued and no pass
    started or merged for the stall time, the sweeper sends the unmerged pass again. The job
    completes with nothing lost, the lost pass tried once (the re-queue spent no try) and no
    other pass re-queued while it was waiting for the worker to start."""
    scene = _scene(cornell, 32, 24, 16)
    store = JobStore.from_url(own_redis.url, prefix)
    with _api(own_redis.url, prefix) as api:
        job_id = _submit(api, scene, 16, 8)  # 4 tiles x 2 passes
        lost = (job_id, 1, 1)
        assert store.r.lrem(_queue_keys(0)[0], 1, _queued_passes(store, 0)[lost]) == 1
        node = nodes.start(1)
        nodes.wait_warm(store, node, 1)
        assert _finished(store, job_id, timeout=60) == "done", _stuck(store, job_id)
        # Re-queued once, after the other seven were merged: the one pass, nothing else.
        assert store.r.hget(store.job_key(job_id), "stalls") == b"1"
        plan = store.get_job(job_id).plan
        assert _attempts(store, job_id) == {f"{t}:{p}": 1 for t, p in plan.order()}
        assert store.metrics()["passes_requeued"] == 1
        _assert_nothing_lost(api, store, job_id, scene)
    store.r.close()


# --- 1. workers SIGKILLed at random moments, repeatedly ------------------------------------------
@pytest.mark.slow
def test_workers_killed_repeatedly(own_redis, nodes, prefix, cornell):
    """Six SIGKILLs at random moments of one job (seeded): pool processes (Celery forks a new
    one; the task comes back at once, ``task_reject_on_worker_lost``) and whole nodes (restarted;
    their tasks come back after the visibility timeout)."""
    kills = ["pool", "pool", "pool", "pool", "node", "node"]
    rng = random.Random(7)
    rng.shuffle(kills)
    moments = sorted(rng.uniform(0.05, 0.85) for _ in kills)
    # Each kill costs at most one try of the passes in flight: with more tries than kills no pass
    # can run out of them (the cap itself is tested below).
    env = {"LUCENT_MAX_ATTEMPTS": str(len(kills) + 1)}
    # 12 tiles x 64 passes = 768 tasks of 64k paths (~10 ms of rendering each on the packet
    # kernel): long enough that a kill lands inside a task, not in the gap between two (with
    # 2k-path tasks of the scalar kernel the pool processes waited for the broker much of the
    # time, and in half the runs no kill cost a pass a try).
    scene = _scene(cornell, 64, 48, 16384)
    node = nodes.start(2, **env)
    store = JobStore.from_url(own_redis.url, prefix)
    nodes.wait_warm(store, node, 2)
    with _api(own_redis.url, prefix) as api:
        job_id = _submit(api, scene, 16, 256)
        total = store.get_job(job_id).plan.n_tasks
        kills_done = 0
        for kind, moment in zip(kills, moments, strict=True):
            # The moment, then a pool process with a task in hand. Not both processes warm
            # first: while a new one warmed its JIT the other rendered on, and on a busy machine
            # it rendered the job past the later moments, even to its end (3 kills in a CI run).
            _until(lambda m=moment: store.get_job(job_id).tasks_merged >= m * total, TIMEOUT,
                   f"{moment:.0%} of the job")
            busy = nodes.wait_busy(store, node) if kind == "pool" else []
            time.sleep(rng.uniform(0.0, 0.03))  # anywhere in a task: render, write or merge
            if store.get_status(job_id) != "running":
                break  # done before the last moments: later kills would test nothing
            kills_done += 1
            if kind == "pool":
                os.kill(rng.choice(busy), signal.SIGKILL)
            else:
                nodes.kill(node)
                node = nodes.start(2, **env)
            time.sleep(1.0)  # the victims' heartbeats expire (3 x 0.25 s) before the next choice
        assert kills_done == len(kills)  # every moment comes before the job's end
        assert _finished(store, job_id) == "done", _stuck(store, job_id)
        assert max(_attempts(store, job_id).values()) >= 2  # the kills did cost passes a try
        _assert_nothing_lost(api, store, job_id, scene)


@pytest.mark.slow
def test_a_node_killed_mid_sequence_loses_no_frame(own_redis, nodes, prefix, cornell):
    """A job of three frames; its worker node SIGKILLed (main process and pool) at 40 % of it
    and another started: the job ends done, every pixel of every frame with exactly ``spp``
    samples and each frame the local render of its patched scene."""
    from services.farm.frames import apply_patch

    scene = _scene(cornell, 32, 24, 256)
    frames = [[], [{"op": "replace", "path": "/camera/position/0", "value": 0.3}],
              [{"op": "replace", "path": "/materials/white/albedo", "value": [0.4, 0.4, 0.4]}]]
    node = nodes.start(2)
    store = JobStore.from_url(own_redis.url, prefix)
    nodes.wait_warm(store, node, 2)
    with _api(own_redis.url, prefix) as api:
        r = api.post("/api/jobs", json={"scene": scene, "frames": frames, "tile_size": 16,
                                        "spp_per_pass": 8, "max_spp_per_pass": 8})
        assert r.status_code == 201, r.text
        job_id = r.json()["id"]
        total = r.json()["tasks_total"]
        _until(lambda: store.get_job(job_id).tasks_merged >= 0.4 * total, TIMEOUT, "40 %")
        nodes.kill(node)
        assert store.get_status(job_id) == "running"
        nodes.start(2)
        assert _finished(store, job_id) == "done", _stuck(store, job_id)
        assert store.r.scard(store.k("job", job_id, "merged")) == total
        for i, patch in enumerate(frames):
            frame, _ = assemble(store, job_id, i)
            assert (frame.count + frame.dropped == 256).all(), f"frame {i}"
            image = np.load(io.BytesIO(
                api.get(f"/api/jobs/{job_id}/frames/{i}/image.npy").content))
            np.testing.assert_allclose(image, render(apply_patch(scene, patch)), rtol=1e-5,
                                       atol=1e-7)


# --- 2. a worker cut off from the network mid-task -----------------------------------------------
class Partition:
    """A TCP proxy in front of Redis that can be cut and healed, for one worker node.

    Cut, it forwards nothing in either direction and accepts no new upstream connection, but
    closes nothing: as in a network partition, no FIN or RST reaches either side, the bytes
    already sent wait (here in the proxy, there in TCP retransmissions) and are delivered when the
    partition heals. ``cut_on``: cut just before the ``n``-th client write that matches this
    pattern, which is held with the rest, so the cut falls at a chosen point of a task."""

    def __init__(self, upstream_port: int, cut_on: re.Pattern[bytes], n: int):
        self.upstream_port = upstream_port
        self.cut_on, self.n, self.seen = cut_on, n, 0
        self.trigger = b""
        self.open = threading.Event()
        self.open.set()
        self.cut_done = threading.Event()
        self.trigger_delivered = threading.Event()  # the held write reached Redis after a heal
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self._sockets: list[socket.socket] = []
        self._lock = threading.Lock()
        threading.Thread(target=self._accept, daemon=True).start()

    @property
    def url(self) -> str:
        return f"redis://127.0.0.1:{self.port}/0"

    def heal(self) -> None:
        self.open.set()

    def close(self) -> None:
        self.open.set()
        self.listener.close()
        for s in self._sockets:
            with contextlib.suppress(OSError):
                s.close()

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self.listener.accept()
            except OSError:
                return
            threading.Thread(target=self._connect, args=(client,), daemon=True).start()

    def _connect(self, client: socket.socket) -> None:
        self.open.wait()
        upstream = socket.create_connection(("127.0.0.1", self.upstream_port))
        self._sockets += [client, upstream]
        threading.Thread(target=self._pump, args=(client, upstream, True), daemon=True).start()
        threading.Thread(target=self._pump, args=(upstream, client, False), daemon=True).start()

    def _pump(self, src: socket.socket, dst: socket.socket, from_client: bool) -> None:
        try:
            while data := src.recv(65536):
                if from_client and self.cut_on.search(data):
                    with self._lock:
                        self.seen += 1
                        if self.seen == self.n:
                            self.trigger = data
                            self.open.clear()
                            self.cut_done.set()
                self.open.wait()
                dst.sendall(data)
                if from_client and data is self.trigger:
                    self.trigger_delivered.set()
        except OSError:
            pass
        finally:
            for s in (src, dst):
                with contextlib.suppress(OSError):
                    s.shutdown(socket.SHUT_RDWR)


# A rendered pass sent to Redis: the merge's first read (``_MERGE_READ``), an EVAL of 8 keys, the
# merged set then the pass buffer's, then 6 more, with a time to live for the buffer (its 4th
# argument), which the read stores. (A read again after a conflict stores nothing: ''.)
PUT_PASS = re.compile(
    rb"\$4\r\nEVAL\r\n.*?\r\n\$1\r\n8\r\n\$\d+\r\n[^\r\n]*:merged\r\n"
    rb"\$\d+\r\n[^\r\n]*:pass:(\d+):(\d+)\r\n(?:\$\d+\r\n[^\r\n]*\r\n){6}"
    rb"\$\d+\r\n\d+:\d+\r\n\$\d+\r\n\d+\r\n\$1\r\n1\r\n\$[1-9]\d*\r\n\d+\r\n", re.S)


@pytest.mark.slow
def test_worker_cut_off_mid_task(own_redis, nodes, prefix, cornell):
    """Node A reaches Redis through a ``Partition`` that is cut just as A sends its second
    rendered pass. A's heartbeats are cut off too: once its heartbeat has expired the sweeper
    sends the pass again (``lost_requeues``; before, the pass waited for the visibility timeout),
    node B (on Redis directly) renders and merges it, and the job completes while A's task is
    still blocked. Then the partition heals and A's pass, held in flight all along, reaches Redis
    late; it is dropped as merged already (by A's own merge when its task goes on, or by the
    sweeper) instead of being counted a second time, and no pass buffer is left behind.

    B starts once A is cut: with both nodes on the queue from the start, a busy machine could let
    B render every pass before A, behind the proxy, came to its second."""
    proxy = Partition(own_redis.port, PUT_PASS, n=2)
    store = JobStore.from_url(own_redis.url, prefix)
    try:
        node_a = nodes.start(1, redis_url=proxy.url)
        nodes.wait_warm(store, node_a, 1)
        # 4 tiles x 16 passes = 64 tasks, of 16 K paths each (~3 ms on the packet kernel)
        scene = _scene(cornell, 32, 32, 1024)
        with _api(own_redis.url, prefix) as api:
            job_id = _submit(api, scene, 16, 64)
            n_tasks = store.get_job(job_id).plan.n_tasks
            assert proxy.cut_done.wait(TIMEOUT), nodes.logs()
            assert store.get_job(job_id).tasks_merged == 1  # A's first pass, and no other yet
            node_b = nodes.start(1)
            nodes.wait_warm(store, node_b, 1)
            match = PUT_PASS.search(proxy.trigger)
            tile, pass_index = int(match[1]), int(match[2])
            assert _finished(store, job_id) == "done", nodes.logs()
            assert _attempts(store, job_id)[f"{tile}:{pass_index}"] == 2  # A's try, then B's
            assert store.metrics()["lost_requeues"] == 1  # not the visibility timeout
        late_key = store.pass_key(job_id, tile, pass_index)
        proxy.heal()
        assert proxy.trigger_delivered.wait(30), "A's late pass never reached Redis"
        with _api(own_redis.url, prefix) as api:
            _until(lambda: not store.r.exists(late_key)
                   and not store.r.sismember(store.k("pending"), late_key), 30,
                   "the late pass dropped")
            assert store.get_job(job_id).tasks_merged == n_tasks
            _assert_nothing_lost(api, store, job_id, scene)
        assert store.get_job(job_id).samples_merged == 32 * 32 * 1024
    finally:
        store.r.close()
        nodes.stop()
        proxy.close()


# --- 3. Redis restarted mid-job ------------------------------------------------------------------
def _restart_redis(server: EmbeddedRedis, appendonly: bool) -> EmbeddedRedis:
    """SIGKILL redis-server (no shutdown save) and start a new one on the same port and folder."""
    assert server.proc is not None
    server.proc.kill()
    server.proc.wait()
    time.sleep(1.0)  # down long enough for every client to see it gone
    return EmbeddedRedis(port=server.port, data_dir=server.data_dir,
                         appendonly=appendonly).start()


def _restart_redis_a_third_into_a_job(server: EmbeddedRedis, api: TestClient, store: JobStore,
                                      scene: dict, appendonly: bool
                                      ) -> tuple[EmbeddedRedis, str, int]:
    """Submit the job (12 tiles x 32 passes = 384 tasks), restart Redis once a third of it is
    merged; the new server, the job's id and its task count."""
    job_id = _submit(api, scene, 16, 4)
    total = store.get_job(job_id).plan.n_tasks
    _until(lambda: store.get_job(job_id).tasks_merged >= total // 3, TIMEOUT,
           "a third of the job")
    return _restart_redis(server, appendonly=appendonly), job_id, total


@pytest.mark.slow
def test_redis_restarted_with_persistence(tmp_path, prefix, cornell):
    """With ``appendonly yes`` (the deploy files' Redis) a Redis killed and restarted mid-job
    comes back with the queue, the jobs and the accumulations; passes in flight during the
    outage are re-run (their acknowledgements were lost with the connections) and merged once."""
    data = tmp_path / "redis"
    data.mkdir()
    server = EmbeddedRedis(data_dir=str(data), appendonly=True).start()
    nodes = Nodes(server.url, prefix, tmp_path)
    store = JobStore.from_url(server.url, prefix)
    try:
        node = nodes.start(2)
        nodes.wait_warm(store, node, 2)
        scene = _scene(cornell, 64, 48, 128)
        with _api(server.url, prefix) as api:
            server, job_id, total = _restart_redis_a_third_into_a_job(server, api, store, scene,
                                                                      appendonly=True)
            assert store.get_job(job_id).tasks_merged >= total // 3  # nothing merged was lost
            try:
                status = _finished(store, job_id)
            except AssertionError as err:
                raise AssertionError(f"{err}\n{nodes.logs()}") from None
            assert status == "done", nodes.logs()
            assert node.poll() is None
            _assert_nothing_lost(api, store, job_id, scene)
    finally:
        store.r.close()
        nodes.stop()
        server.stop()


class InProcessWorker:
    """A worker process's state in this process, on an embedded Redis with an append-only file
    that ``kill_and_restart`` SIGKILLs and starts again on the same port and folder 1 s later."""

    def __init__(self, tmp_path: Path, prefix: str, monkeypatch) -> None:
        from worker import runtime

        data = tmp_path / "redis"
        data.mkdir()
        self.server = EmbeddedRedis(data_dir=str(data), appendonly=True).start()
        self.servers = [self.server]
        self.done = threading.Event()
        self.store = JobStore.from_url(self.server.url, prefix)
        self.state = runtime.WorkerState()
        self.state.settings = Settings(redis_url=self.server.url, key_prefix=prefix,
                                       redis_outage_wait=30, **TIMINGS)
        monkeypatch.setattr(runtime, "STATE", self.state)

    def kill_and_restart(self) -> None:
        def restarted() -> None:
            time.sleep(1.0)
            self.servers.append(EmbeddedRedis(port=self.server.port,
                                              data_dir=self.server.data_dir,
                                              appendonly=True).start())
            # redis-server dies with the thread that started it (its parent-death signal)
            self.done.wait()

        self.server.proc.kill()
        self.server.proc.wait()
        threading.Thread(target=restarted, daemon=True).start()

    def close(self) -> None:
        self.store.r.close()
        self.state.store.close()
        for server in self.servers:
            server.stop()
        self.done.set()


@pytest.fixture
def in_process_worker(tmp_path, prefix, monkeypatch) -> Iterator[InProcessWorker]:
    w = InProcessWorker(tmp_path, prefix, monkeypatch)
    yield w
    w.close()


@pytest.mark.parametrize("where", ["begin_view", "merge_pass_buffer"])
def test_a_pass_caught_by_a_redis_restart_waits_for_redis_and_merges(in_process_worker, prefix,
                                                                     cornell, monkeypatch,
                                                                     where):
    """Redis SIGKILLed while a worker process talks to it, at the start of a pass (as ``lucent
    up``'s test caught it) or once rendered: the task cannot give its message back (its channel
    died with the connection; the message waits in kombu's unacked hash for the stall rule), so
    it waits for Redis and runs the pass again, without counting the same delivery twice as a
    try. Without that the task raised ``Reject`` and the job's last pass came minutes later."""
    from celery.exceptions import Reject

    from worker import tasks

    w = in_process_worker
    with _api(w.server.url, prefix) as api:
        job_id = _submit(api, _scene(cornell, 16, 16, 4), 16, 4)
    call = getattr(w.state.store, where)
    calls = []

    def redis_dies_here(*args, **kwargs):
        calls.append(args)
        if len(calls) == 1:
            w.kill_and_restart()
        return call(*args, **kwargs)

    monkeypatch.setattr(w.state.store, where, redis_dies_here)
    try:
        result = tasks.render_pass(job_id, 0, 0)
    except Reject as err:
        raise AssertionError(f"the pass was given up: {err}") from None
    assert result == "merged" and len(calls) == 2
    assert w.store.is_merged(job_id, 0, 0) and w.store.get_job(job_id).tasks_merged == 1
    assert w.store.attempts(job_id, 0, 0) == 1  # one delivery, one try


def test_a_chain_cut_by_a_redis_restart_goes_on(in_process_worker, prefix, cornell, monkeypatch):
    """A job with a target error: its pass merged, then Redis died as the worker queued the
    tile's next pass (kombu's publish gives up: ``OperationalError``). The task waits for Redis,
    finds its pass merged and queues the next one itself. It used to record a failed try of the
    merged pass, send it again, and leave the tile's chain to the stall rule."""
    from kombu.exceptions import OperationalError

    from services.farm import queue
    from worker import tasks

    w = in_process_worker
    scene = _scene(cornell, 16, 16, 64)
    scene["render"]["target_error"] = 0.01
    with _api(w.server.url, prefix) as api:
        job_id = _submit(api, scene, 16, 8)  # 8 passes of 8 samples
    sent, published = [], []
    monkeypatch.setattr(queue, "enqueue",
                        lambda celery, job, todo, *args, **kwargs: sent.append((job, todo)))

    def publish_fails(args, **kwargs):
        published.append(args)
        if len(published) == 1:
            w.kill_and_restart()
            raise OperationalError("Error 111 connecting to 127.0.0.1. Connection refused.")

    monkeypatch.setattr(tasks.render_pass, "apply_async", publish_fails)
    assert tasks.render_pass(job_id, 0, 0) == "duplicate"
    assert published == [(job_id, 0, 1)]  # the chain's own attempt, which failed
    assert sent == [(job_id, [(0, 1)])]  # then the next pass, queued after the outage
    assert w.store.is_merged(job_id, 0, 0) and w.store.attempts(job_id, 0, 0) == 1
    assert w.store.get_job(job_id).status == "running"  # no failure recorded on the tile
    assert not w.store.r.hgetall(w.store.k("job", job_id, "tile_error"))


@pytest.mark.slow
def test_redis_restarted_without_persistence_loses_the_job_clearly(tmp_path, prefix, cornell):
    """Without persistence a restarted Redis is empty: the job's in-flight state (its hash,
    scene, tiles, accumulations) and its queued passes are gone. What documents that here: its
    record stays and is failed with the reason by a sweep, so the API answers it and ``lucent
    submit --wait``'s client stops instead of polling forever; the passes that were in flight are
    discarded (not left pending), and the same workers render a new job."""
    server = EmbeddedRedis().start()
    nodes = Nodes(server.url, prefix, tmp_path)
    store = JobStore.from_url(server.url, prefix)
    try:
        node = nodes.start(2)
        nodes.wait_warm(store, node, 2)
        scene = _scene(cornell, 64, 48, 128)
        with _api(server.url, prefix) as api:
            server, job_id, _ = _restart_redis_a_third_into_a_job(server, api, store, scene,
                                                                  appendonly=False)
            # Its record stays, and is failed with the reason by a sweep (LOST_AFTER after it
            # was submitted): the API answers it, and the client's wait ends
            lost = _until(lambda: (j := api.get(f"/api/jobs/{job_id}").json())["status"]
                          == "failed" and j, LOST_AFTER + 30, "the job reported lost")
            assert "Redis lost" in lost["error"], lost
            client = Client("http://testserver")
            client.http = api
            assert client.wait(job_id, progress=False)["status"] == "failed"
            assert store.r.llen("celery") == 0
            _until(lambda: store.r.scard(store.k("pending")) == 0, 30,
                   "in-flight passes discarded")
            assert not store.r.exists(store.job_key(job_id))
            # The farm itself is fine: the same workers render the next job.
            small = _scene(cornell, 32, 24, 16)
            again = _submit(api, small, 16, 8)
            assert _finished(store, again) == "done", nodes.logs()
            assert node.poll() is None
            _assert_nothing_lost(api, store, again, small)
    finally:
        store.r.close()
        nodes.stop()
        server.stop()


# --- 4. the API restarted mid-job ----------------------------------------------------------------
@pytest.mark.slow
def test_api_process_killed_mid_job(own_redis, nodes, prefix, cornell, tmp_path):
    """The API as its own uvicorn process, SIGKILLed mid-job (no lifespan shutdown) and started
    again: the workers never needed it, and the new one serves the finished job."""
    import httpx

    store = JobStore.from_url(own_redis.url, prefix)
    node = nodes.start(2)
    nodes.wait_warm(store, node, 2)
    port = free_port()
    # archive_done off, as the other fault tests' API: the check below counts the merged passes
    env = worker_env(own_redis.url, 1, {**FAULT_ENV, "LUCENT_KEY_PREFIX": prefix,
                                        "LUCENT_ARCHIVE_DONE": "0"})

    def serve() -> subprocess.Popen:
        return subprocess.Popen(
            [sys.executable, "-m", "uvicorn", "services.api.main:app", "--port", str(port),
             "--log-level", "warning"], cwd=ROOT, env=env,
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def up(http: httpx.Client) -> bool:
        with contextlib.suppress(httpx.HTTPError):
            return http.get("/readyz").status_code == 200
        return False

    scene = _scene(cornell, 64, 48, 128)
    api = serve()
    try:
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=30) as http:
            _until(lambda: up(http), 60, "the API")
            r = http.post("/api/jobs", json={"scene": scene, "tile_size": 16, "spp_per_pass": 4,
                                             "max_spp_per_pass": 4})
            job_id = r.json()["id"]
            total = r.json()["tasks_total"]
            _until(lambda: store.get_job(job_id).tasks_merged >= total // 4, TIMEOUT,
                   "a quarter of the job")
            api.kill()
            api.wait()
            assert store.get_status(job_id) == "running"
            api = serve()
            _until(lambda: up(http), 60, "the API again")
            _until(lambda: http.get(f"/api/jobs/{job_id}").json()["status"] == "done", TIMEOUT,
                   "the job")
        with _api(own_redis.url, prefix) as check:
            _assert_nothing_lost(check, store, job_id, scene)
    finally:
        terminate(api, 10.0)
        store.r.close()


# --- 5. a task that hangs is stopped by the time limit and re-run --------------------------------
@pytest.mark.slow
@pytest.mark.parametrize(("mode", "limit"), [("sleep", "soft"), ("hang", "hard")])
def test_a_hanging_pass_is_stopped_and_run_again(own_redis, nodes, prefix, cornell, mode, limit):
    """One pass hangs on its first try. ``sleep`` (in Python) is interrupted by the soft limit
    (4 s): the task records the timeout and sends itself again. ``hang`` ignores the soft limit
    (like a kernel that never returns to Python) and is killed at the hard limit (6 s): the
    message goes back on the queue (``task_acks_on_timeout = False``). Either way the second try
    renders it and the job completes."""
    scene = _scene(cornell, 32, 24, 16)
    store = JobStore.from_url(own_redis.url, prefix)
    with _api(own_redis.url, prefix) as api:
        tile = 0
        node = nodes.start(2, app="faulty_worker", LUCENT_TEST_FAULT=f"{tile}:1:{mode}")
        nodes.wait_warm(store, node, 2)
        job_id = _submit(api, scene, 16, 8)  # 2 tiles x 2 passes
        assert _finished(store, job_id, timeout=60) == "done", nodes.logs()
        assert _attempts(store, job_id)[f"{tile}:1"] == 2
        if limit == "soft":
            assert "timed out" in store.tile_errors(job_id)[tile]
        _assert_nothing_lost(api, store, job_id, scene)


# --- 6. a scene that crashes the tracer fails its job after a bounded number of tries -------------
@pytest.mark.slow
@pytest.mark.parametrize("mode", ["raise", "segv"])
def test_a_crashing_pass_fails_its_job_after_max_attempts(own_redis, nodes, prefix, cornell,
                                                          mode):
    """A pass that fails on every try — by an exception (the task retries itself) or by killing
    its process with SIGSEGV (Celery redelivers it) — is tried exactly ``max_attempts`` (3)
    times; then its tile and its job fail with the reason, and the node goes on working."""
    scene = _scene(cornell, 32, 24, 16)
    store = JobStore.from_url(own_redis.url, prefix)
    with _api(own_redis.url, prefix) as api:
        node = nodes.start(2, app="faulty_worker", LUCENT_TEST_FAULT=f"1:0:{mode}")
        nodes.wait_warm(store, node, 2)
        job_id = _submit(api, scene, 16, 8)
        assert _finished(store, job_id, timeout=90) == "failed", nodes.logs()
        job = api.get(f"/api/jobs/{job_id}").json()
        tries = _attempts(store, job_id)["1:0"]
        if mode == "raise":
            assert tries == 3
            assert "RuntimeError: the tracer failed" in job["error"]
            assert "after 3 tries" in job["error"]
        else:  # three deliveries died with their process; the fourth gives up without running
            assert tries == 4
            assert "gave up after 3 tries" in job["error"]
        assert job["error"].startswith("tile 1: pass 0")
        assert node.poll() is None
        again = _submit(api, scene, 32, 16)  # tile 0 only: the fault is in tile 1
        assert _finished(store, again) == "done"


# --- 7. a worker node SIGKILLed mid-pass: its pass comes back once its heartbeat expires --------
@pytest.mark.slow
def test_a_lost_nodes_pass_is_requeued_once_its_heartbeat_expires(own_redis, prefix, tmp_path):
    """Chaos, with real Celery worker nodes (``bench.worker_loss``, which times it): two nodes of
    one process each, heartbeats every 0.5 s (timeout 1.5 s); the node that begins a job's only
    pass (1 s or more of rendering) has its main process SIGKILLed, and its pool process dies with
    it. The stall time (300 s) and the visibility timeout (900 s) are far away, so only the
    lost-worker rule can bring the pass back: the sweeper sends it again, the other node renders
    it, and the job completes with nothing lost. The pass was tried twice, and the dead process
    holds nothing any more."""
    from bench.worker_loss import TIMINGS, TwoNodes, long_pass_scene, lose_a_worker

    heartbeat = 0.5
    nodes = TwoNodes(own_redis.url, prefix, heartbeat, tmp_path)
    store = JobStore.from_url(own_redis.url, prefix)
    # archive_done off, as the other fault tests' API: the checks below read the job's keys,
    # which the sweeper (every 0.2 s) would otherwise remove once the job is done
    settings = Settings(redis_url=own_redis.url, key_prefix=prefix, api_token=None,
                        heartbeat_interval=heartbeat, sweep_interval=0.2, archive_done=False,
                        **TIMINGS)
    scene = long_pass_scene(1024)
    try:
        nodes.start("a")
        nodes.start("b")
        with TestClient(create_app(settings)) as api:
            loss = lose_a_worker(api, store, nodes, scene, timeout=90.0)
            # Well before the other mechanisms (300 s, 900 s); bench.worker_loss has the figures
            assert loss.requeued < 60.0, loss
            job_id = api.get("/api/jobs").json()["data"][0]["id"]
            assert _attempts(store, job_id) == {"0:0": 2}
            assert store.metrics()["lost_requeues"] == 1
            assert store.lost_holdings() == {}
            _assert_nothing_lost(api, store, job_id, scene)
    finally:
        store.close()
        nodes.stop()


def test_a_tile_waiting_at_the_end_of_its_pilot_is_woken_by_the_merge_that_ends_the_frames(
        in_process_worker, prefix, cornell, monkeypatch):
    """A job with a target error, two tiles: tile 0 ends its pilot first and, the frame's
    estimate there not known yet, waits (its next pass finds nothing to add: ``converged``);
    the worker whose merge ends tile 1's pilot completes the frame's (``FRAME_LOOKED``) and
    queues tile 0's next pass itself (``wake_converged``), not once tile 1's chain has ended.
    Seen failing without the worker's call."""
    from worker import tasks

    w = in_process_worker
    scene = _scene(cornell, 32, 16, 64)
    scene["render"]["target_error"] = 0.01  # (far below what 8 samples a pixel reach)
    with _api(w.server.url, prefix) as api:
        job_id = _submit(api, scene, 16, 8)  # 2 tiles, 8 passes of 8 samples
    published = []
    monkeypatch.setattr(tasks.render_pass, "apply_async",
                        lambda args, **kwargs: published.append(tuple(args)))
    assert tasks.render_pass(job_id, 0, 0) == "merged"  # the first look
    assert tasks.render_pass(job_id, 0, 1) == "merged"  # the rest of the pilot
    assert tasks.render_pass(job_id, 0, 2) == "converged"  # waits
    assert w.store.tile_states(job_id)[0] == "converged"
    assert tasks.render_pass(job_id, 1, 0) == "merged"
    assert (job_id, 0, 3) not in published
    assert tasks.render_pass(job_id, 1, 1) == "merged"  # ends the frame's pilot
    # tile 0's next pass (pass 2 merged empty when it found nothing), then tile 1's chain
    assert published[-2:] == [(job_id, 0, 3), (job_id, 1, 2)]
    assert w.store.tile_states(job_id)[0] == "queued"
    assert tasks.render_pass(job_id, 0, 3) == "merged"


def _one_pass_with_kernel(worker, prefix, cornell, monkeypatch, kernel: str):
    """Tile 0's first pass of a 16×16 Cornell box (one tile, 4 spp) rendered by an in-process
    worker whose ``worker_kernel`` is ``kernel`` (a failed pass fails the test); the merged
    tile's buffer and the compiled scene."""
    from renderer.film.buffer import SampleBuffer
    from renderer.scene import load_scene
    from renderer.scene.compile import compile_scene
    from worker import tasks

    worker.state.settings = worker.state.settings.model_copy(update={"worker_kernel": kernel})
    scene = _scene(cornell, 16, 16, 4)
    with _api(worker.server.url, prefix) as api:
        job_id = _submit(api, scene, 16, 4)

    def failed(store, settings, delivery, tile, pass_index, reason, node):
        raise AssertionError(reason)

    monkeypatch.setattr(tasks, "pass_failed", failed)
    assert tasks.render_pass(job_id, 0, 0) == "merged"
    return (SampleBuffer.from_bytes(worker.store.tile_buffer(job_id, 0)),
            compile_scene(load_scene(scene)))


def test_a_worker_renders_its_passes_with_its_configured_kernel(in_process_worker, prefix,
                                                                 cornell, monkeypatch):
    """A node's ``worker_kernel`` (``lucent worker --kernel``) is the kernel its passes render
    with: with ``wavefront`` the pass goes through the batched kernel (a GPU node's ``gpu``
    through ``render_tile_gpu`` beside it), and the merged tile is that kernel's buffer."""
    import renderer.render as rr

    calls = []
    wavefront = rr.render_tile_wavefront

    def batched(*args, **kwargs):
        calls.append(args[1:7])
        return wavefront(*args, **kwargs)

    monkeypatch.setattr(rr, "render_tile_wavefront", batched)
    merged, cs = _one_pass_with_kernel(in_process_worker, prefix, cornell, monkeypatch,
                                       "wavefront")
    assert calls == [(0, 0, 16, 16, 0, 4)]
    want = rr.render_tile(cs, 0, 0, 16, 16, 0, 4, kernel="scalar")
    np.testing.assert_allclose(merged.sum, want.sum, rtol=1e-10)


def test_a_packet_node_renders_the_scenes_the_packet_kernel_covers(in_process_worker, prefix,
                                                                   cornell, monkeypatch):
    """``worker_kernel`` ``packet``: the Cornell box's pass is the packet kernel's buffer (16
    paths in the vector lanes, ``renderer.packet``), not the scalar kernel's."""
    import renderer.render as rr

    merged, cs = _one_pass_with_kernel(in_process_worker, prefix, cornell, monkeypatch, "packet")
    want = rr.render_tile(cs, 0, 0, 16, 16, 0, 4, kernel="packet")
    np.testing.assert_allclose(merged.sum, want.sum, rtol=1e-12)
    np.testing.assert_array_equal(merged.count, want.count)
    assert not np.allclose(merged.sum, rr.render_tile(cs, 0, 0, 16, 16, 0, 4, kernel="scalar").sum,
                       rtol=1e-6)
