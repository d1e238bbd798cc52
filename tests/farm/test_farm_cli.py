"""``lucent up`` and ``lucent submit`` as a user runs them: real processes, stopped by a signal."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import httpx
import numpy as np
import pytest

from services.launcher import free_port


def test_up_serves_submit_works_and_sigterm_leaves_no_process(tmp_path, tiny_scene, wait_until):
    psutil = pytest.importorskip("psutil")
    port = free_port()
    env = {k: v for k, v in os.environ.items() if k not in ("REDIS_URL", "LUCENT_API_TOKEN")}
    up = subprocess.Popen([sys.executable, "-m", "services.cli", "up", "--port", str(port),
                           "--workers", "1"], env=env, stderr=subprocess.PIPE, text=True)
    url = f"http://127.0.0.1:{port}"
    try:
        def ready():
            try:
                return httpx.get(f"{url}/readyz", timeout=1).status_code == 200
            except httpx.HTTPError:
                return up.poll() is not None
        wait_until(ready, 60, "lucent up to answer", interval=0.2)
        assert up.poll() is None
        scene_path = tmp_path / "box.json"
        scene_path.write_text(json.dumps(tiny_scene))
        out = tmp_path / "box.npy"
        done = subprocess.run(
            [sys.executable, "-m", "services.cli", "submit", str(scene_path), "--server", url,
             "--wait", "-o", str(out), "--quiet"], env=env, capture_output=True, text=True,
            timeout=240)
        assert done.returncode == 0, done.stderr
        assert np.load(out).shape == (24, 32, 3) and np.load(out).any()
        children = psutil.Process(up.pid).children(recursive=True)
        names = {c.name() for c in children}
        assert any("redis" in n for n in names), names  # embedded Redis
        assert len(children) >= 3  # redis-server, the worker node and its pool process
    finally:
        up.send_signal(signal.SIGTERM)
        try:
            up.wait(90)
        except subprocess.TimeoutExpired:
            up.kill()
            raise
    assert up.returncode == 0, up.stderr.read()[-3000:] if up.stderr else ""
    deadline = time.monotonic() + 10
    while any(c.is_running() and c.status() != psutil.STATUS_ZOMBIE for c in children):
        assert time.monotonic() < deadline, [c for c in children if c.is_running()]
        time.sleep(0.1)


def test_submit_reports_the_field_of_an_invalid_scene(tmp_path, client, tiny_scene):
    """``lucent submit`` against a server that refuses the scene: exit 1, the field named."""
    from services.client import Client

    tiny_scene["film"]["width"] = -3
    c = Client("http://testserver")
    c.http = client  # the TestClient speaks httpx's API
    with pytest.raises(ValueError, match="film.width"):
        c.submit(tiny_scene)
