"""Security: the API token on every route that shows farm data, CORS off unless configured, no
server-side path a request can name, a Redis with a password, and Celery refusing pickle."""

from __future__ import annotations

import json
import pickle
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from pathlib import Path, PurePosixPath
from urllib.parse import urlsplit

import pytest
import redis
from fastapi.testclient import TestClient

from renderer.scene.schema import Scene
from services.api import deps
from services.api.main import create_app
from services.api.models import JobCreate
from services.farm.queue import TASK, celery_client
from services.farm.settings import Settings
from services.launcher import free_port, redis_server_binary, start_worker, terminate

TOKEN = "correct-horse-battery-staple"

# The only operations of the OpenAPI document answered without the token: the probes. Besides
# them, the dashboard's pages (``/``, ``/dashboard/...``, out of the schema) are static files.
OPEN_PATHS = {"/healthz", "/readyz"}

EXAMPLE_PARAMS = {"job_id": "nope", "fmt": "png", "name": "nope", "frame": "0"}


@pytest.fixture
def token_client(settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(settings.model_copy(update={"api_token": TOKEN}))) as c:
        yield c


def guarded_requests(app) -> list[tuple[str, str]]:
    """(method, concrete path) of every operation in the app's OpenAPI document but the probes
    (the document lists every route that is not marked ``include_in_schema=False``)."""
    out = []
    for path, operations in app.openapi()["paths"].items():
        if path not in OPEN_PATHS:
            out += [(method.upper(), path.format(**EXAMPLE_PARAMS)) for method in operations]
    return out


# --- the token ----------------------------------------------------------------------------------


def test_every_route_but_probes_and_pages_needs_the_token(token_client, tiny_scene):
    requests = guarded_requests(token_client.app)
    paths = {p for _, p in requests}
    # Every /api route, the dashboard's data routes and /metrics are among them.
    assert {"/api/jobs", "/api/jobs/nope", "/api/jobs/nope/image.png", "/api/jobs/nope/retry",
            "/api/workers", "/api/examples", "/api/examples/nope", "/api/figures",
            "/metrics"} <= paths
    wrong = [{}, {"Authorization": "Bearer"}, {"Authorization": "Bearer wrong"},
             {"Authorization": f"Basic {TOKEN}"}, {"Authorization": TOKEN},
             {"Authorization": f"Bearer {TOKEN}x"}, {"Authorization": f"Bearer {TOKEN[:-1]}"},
             {"X-API-Token": TOKEN}]
    for method, path in requests:
        body = {"scene": tiny_scene} if method == "POST" and path == "/api/jobs" else None
        for headers in wrong:
            r = token_client.request(method, path, headers=headers, json=body)
            assert r.status_code == 401, (method, path, headers, r.status_code)
            assert r.headers["www-authenticate"] == "Bearer"
            if method != "HEAD":  # a HEAD answer has no body
                assert set(r.json()) == {"detail"} and "token" in r.json()["detail"]
        r = token_client.request(method, path, json=body,
                                 headers={"Authorization": f"Bearer {TOKEN}"})
        assert r.status_code != 401, (method, path)
    # Nothing was created by the refused submissions; the accepted one is the only job.
    jobs = token_client.get("/api/jobs", headers={"Authorization": f"Bearer {TOKEN}"}).json()
    assert jobs["count"] == 1


def test_open_routes_show_no_farm_data(token_client):
    assert token_client.get("/healthz").json() == {"status": "ok"}
    # Not ready (no worker beats on this prefix), and saying so in general words only.
    assert token_client.get("/readyz").json() == {"status": "unavailable", "reasons": [
        "no live workers: no worker process has sent a heartbeat within its timeout"]}
    for path in ("/", "/openapi.json", "/docs"):
        assert token_client.get(path).status_code == 200
    assert token_client.get("/dashboard/figures/nope.png").status_code == 404


def test_the_token_is_compared_in_constant_time(token_client, monkeypatch):
    calls = []
    real = deps.secrets.compare_digest

    def spy(a, b):
        calls.append((a, b))
        return real(a, b)

    monkeypatch.setattr(deps.secrets, "compare_digest", spy)
    assert token_client.get("/api/jobs", headers={"Authorization": "Bearer nope"}
                            ).status_code == 401
    assert token_client.get("/api/jobs", headers={"Authorization": f"Bearer {TOKEN}"}
                            ).status_code == 200
    assert calls == [(b"nope", TOKEN.encode()), (TOKEN.encode(), TOKEN.encode())]


# --- CORS ---------------------------------------------------------------------------------------

ORIGIN = "https://evil.example"


def test_cors_is_off_by_default(client):
    r = client.get("/api/jobs", headers={"Origin": ORIGIN})
    assert r.status_code == 200
    assert not any(h.startswith("access-control-") for h in r.headers)
    preflight = client.options("/api/jobs", headers={
        "Origin": ORIGIN, "Access-Control-Request-Method": "POST",
        "Access-Control-Request-Headers": "authorization,content-type"})
    assert preflight.status_code == 405
    assert "access-control-allow-origin" not in preflight.headers


def test_cors_allows_the_configured_origins_only(settings, monkeypatch):
    allowed = "https://farm.example.org"
    monkeypatch.setenv("LUCENT_CORS_ORIGINS", f"{allowed}, https://other.example.org")
    configured = Settings(redis_url=settings.redis_url, key_prefix=settings.key_prefix)
    assert configured.cors_origins == [allowed, "https://other.example.org"]
    with TestClient(create_app(configured)) as c:
        r = c.get("/api/jobs", headers={"Origin": allowed})
        assert r.headers["access-control-allow-origin"] == allowed
        assert "access-control-allow-credentials" not in r.headers
        preflight = c.options("/api/jobs", headers={
            "Origin": allowed, "Access-Control-Request-Method": "POST",
            "Access-Control-Request-Headers": "authorization,content-type"})
        assert preflight.status_code == 200
        assert preflight.headers["access-control-allow-origin"] == allowed
        assert "authorization" in preflight.headers["access-control-allow-headers"].lower()
        # Another origin gets no grant, simple request or preflight.
        r = c.get("/api/jobs", headers={"Origin": ORIGIN})
        assert "access-control-allow-origin" not in r.headers
        preflight = c.options("/api/jobs", headers={
            "Origin": ORIGIN, "Access-Control-Request-Method": "POST"})
        assert preflight.status_code == 400
        assert "access-control-allow-origin" not in preflight.headers


# --- no server-side paths -----------------------------------------------------------------------


def free_text_fields(schema: dict) -> set[str]:
    """``Model.field`` for every string property that is not an enum or a constant, and
    ``Model.*`` for every mapping with free-text keys, across a JSON schema's definitions."""
    found = set()
    models = dict(schema.get("$defs", {}))
    models[schema.get("title", "root")] = schema

    def is_free_text(prop: dict) -> bool:
        options = prop.get("anyOf", [prop])
        return any(o.get("type") == "string" and "enum" not in o and "const" not in o
                   for o in options)

    for model, definition in models.items():
        for name, prop in definition.get("properties", {}).items():
            if is_free_text(prop):
                found.add(f"{model}.{name}")
            if prop.get("type") == "object" and "additionalProperties" in prop:
                found.add(f"{model}.{name}.*")
    return found


def test_no_request_field_can_name_a_server_path():
    """Every free-text field a request has, reviewed: only ``Mesh.path`` names a file, and the
    API refuses it (``load_scene`` without ``allow_paths``). A new one fails this test until it
    is reviewed and added here."""
    scene_fields = free_text_fields(Scene.model_json_schema())
    assert scene_fields == {
        "Mesh.path",  # refused by the API (test below); the CLI alone reads mesh files
        "Mesh.asset",  # "sha256:" and 64 hex digits (pattern-checked), a content address
        "AssetRef.asset",  # the same content address, in a file reference
        # a file reference: a path is refused without allow_paths, by name
        # (tests/renderer/scene/test_environment_load.py)
        "Environment.image", "BitmapTexture.image",
        "Mesh.material", "Sphere.material", "Quad.material", "Box.material",  # names in
        "Scene.materials.*",  # `materials`, looked up there, never opened
    }
    assert free_text_fields(JobCreate.model_json_schema()) == {"JobCreate.name",
                                                               "JobCreate.scene.*"}


@pytest.fixture
def file_opens() -> Iterator[list[str]]:
    """Every file opened while the test runs (an audit hook, PEP 578; hooks cannot be removed,
    so this one goes quiet at the end)."""
    opened: list[str] = []
    active = [True]

    def hook(event: str, args: tuple) -> None:
        if active[0] and event == "open" and isinstance(args[0], str | bytes | Path):
            opened.append(str(args[0]))

    sys.addaudithook(hook)
    yield opened
    active[0] = False


def test_a_request_never_opens_a_path_it_names(client, tiny_scene, tmp_path, file_opens):
    secret = tmp_path / "secret.json"
    secret.write_text(json.dumps({"vertices": [[0, 0, 0]], "triangles": [[0, 0, 0]]}))
    file_opens.clear()  # the write above
    name = str(secret)
    traversal = "../" * 12 + str(PurePosixPath(*secret.parts[1:]))
    scene = json.loads(json.dumps(tiny_scene))
    scene["materials"][name] = scene["materials"].pop("white")
    for obj in scene["objects"]:
        if obj["material"] == "white":
            obj["material"] = name
    for path in (name, traversal, f"file://{name}"):
        mesh = {"type": "mesh", "path": path, "material": name}
        r = client.post("/api/jobs", json={"scene": {**scene, "objects": [*scene["objects"],
                                                                          mesh]}, "name": name})
        assert r.status_code == 422
        assert "command line" in r.text
    # A texture's or the environment's image named by a path: refused by its field, unread
    for path in (name, traversal, f"file://{name}"):
        textured = {**scene, "materials": {**scene["materials"], "tex": {
            "type": "diffuse", "albedo": {"type": "bitmap", "image": path}}}}
        r = client.post("/api/jobs", json={"scene": textured, "name": name})
        assert r.status_code == 422 and "command line" in r.text, r.text
        assert "materials" in r.text and "image" in r.text
        lit = {k: v for k, v in scene.items() if k != "background"}
        r = client.post("/api/jobs", json={"scene": {**lit, "environment": {"image": path}}})
        assert r.status_code == 422 and "command line" in r.text, r.text
        assert "environment" in r.text
    # An asset is a content address, never a path: a name that is not one is refused by its
    # field, and a well-formed one the farm does not have (never uploaded) by its field too.
    for asset in (name, traversal, "sha256:" + "0" * 64):
        mesh = {"type": "mesh", "asset": asset, "material": name}
        r = client.post("/api/jobs", json={"scene": {**scene, "objects": [*scene["objects"],
                                                                          mesh]}, "name": name})
        assert r.status_code == 422, r.text
        assert "objects" in r.text and "asset" in r.text
    assert "unknown asset" in r.text
    for url in (f"/api/assets/{traversal}", f"/api/assets/{name}", "/api/assets/..%2F..%2Fx"):
        assert client.get(url).status_code == 404
    # A material named like a path is only a name: the job is accepted, nothing is read.
    assert client.post("/api/jobs", json={"scene": scene, "name": name}).status_code == 201
    for url in (f"/api/examples/{traversal}", "/api/examples/..%2F..%2Fpyproject",
                f"/dashboard/figures/{traversal}", "/dashboard/figures/..%2F..%2FREADME.md",
                f"/api/jobs/{traversal}", f"/api/jobs/{name}/image.png"):
        assert client.get(url).status_code == 404, url
    assert not [p for p in file_opens if "secret" in p or "pyproject" in p or "README" in p]


# --- Redis with a password ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def redis_with_password(tmp_path_factory) -> Iterator[str]:
    """A redis-server that requires a password; yields its URL with the password in it."""
    password = uuid.uuid4().hex
    port = free_port()
    proc = subprocess.Popen(
        [redis_server_binary(), "--port", str(port), "--bind", "127.0.0.1",
         "--requirepass", password, "--dir", str(tmp_path_factory.mktemp("redis-pw")),
         "--save", "", "--appendonly", "no", "--loglevel", "warning"],
        stdout=subprocess.DEVNULL)
    url = f"redis://:{password}@127.0.0.1:{port}/0"
    client = redis.Redis.from_url(url)
    deadline = time.monotonic() + 20
    while True:
        try:
            client.ping()
            break
        except redis.ConnectionError:
            assert proc.poll() is None and time.monotonic() < deadline, "redis-server failed"
            time.sleep(0.05)
    client.close()
    yield url
    terminate(proc, 10.0)


def test_a_redis_password_is_required_and_used(redis_with_password, settings):
    password = urlsplit(redis_with_password).password
    bare = redis_with_password.replace(f":{password}@", "")
    with pytest.raises(redis.AuthenticationError):
        redis.Redis.from_url(bare).ping()
    # The service with the password in REDIS_URL serves; the broker client authenticates too.
    good = settings.model_copy(update={"redis_url": redis_with_password})
    with TestClient(create_app(good)) as c:
        # Redis answered (the only reason left is the workers this test does not start)
        assert c.get("/readyz").json()["reasons"] == [
            "no live workers: no worker process has sent a heartbeat within its timeout"]
        with c.app.state.celery.connection_for_write() as conn:
            conn.ensure_connection(max_retries=1)
    # A wrong password stops the service at start with Redis's own reason, not later.
    wrong = settings.model_copy(update={"redis_url": redis_with_password.replace(password,
                                                                                 "wrong")})
    with pytest.raises(redis.AuthenticationError), TestClient(create_app(wrong)):
        pass


@pytest.mark.slow
def test_a_job_runs_on_a_redis_with_a_password(redis_with_password, tiny_scene, tmp_path,
                                               wait_for_job):
    """API and a real worker on a password-protected Redis: the job completes."""
    prefix = f"lucent-test-pw-{uuid.uuid4().hex[:8]}"
    settings = Settings(redis_url=redis_with_password, key_prefix=prefix)
    log = tmp_path / "worker.log"
    with open(log, "w") as out:
        proc = start_worker(redis_with_password, concurrency=1, name=f"{prefix}@%h", log=out,
                            extra_env={"LUCENT_KEY_PREFIX": prefix, "LUCENT_API_TOKEN": ""})
    try:
        with TestClient(create_app(settings)) as c:
            r = c.post("/api/jobs", json={"scene": tiny_scene})
            assert r.status_code == 201, r.text
            job = wait_for_job(c, r.json()["id"])
            assert job["status"] == "done", (job, log.read_text()[-2000:])
            assert job["samples_merged"] == job["samples_planned"]
    finally:
        terminate(proc, 30.0)
    assert urlsplit(redis_with_password).password not in log.read_text()


# --- Celery accepts JSON only -------------------------------------------------------------------


class TouchOnUnpickle:
    """Unpickling this object creates ``path``: the proof that a worker ran sent code."""

    def __init__(self, path: Path):
        self.path = path

    def __reduce__(self):
        return (Path.touch, (self.path,))


def test_a_pickle_message_is_refused_and_nothing_runs(farm, farm_client, tiny_scene, tmp_path,
                                                      wait_for_job, wait_until):
    marker = tmp_path / "pwned"
    task_id = uuid.uuid4().hex
    body = ((TouchOnUnpickle(marker), 0, 0), {}, {"callbacks": None, "errbacks": None,
                                                  "chain": None, "chord": None})
    assert pickle.loads(pickle.dumps(TouchOnUnpickle(marker))) is None and marker.exists()
    marker.unlink()  # the payload works: unpickled, it creates the file
    app = celery_client(farm.settings)
    log_before = farm.log.read_text()
    with app.connection_for_write() as conn:
        # A task message exactly like Celery's (protocol 2) but serialized with pickle.
        conn.Producer().publish(
            body, routing_key="celery", exchange="", serializer="pickle",
            headers={"lang": "py", "task": TASK, "id": task_id, "root_id": task_id,
                     "parent_id": None, "group": None, "retries": 0, "eta": None,
                     "expires": None, "timelimit": [None, None], "argsrepr": "",
                     "kwargsrepr": "", "origin": "test", "ignore_result": True},
            correlation_id=task_id, delivery_mode=2)

    def refused() -> bool:
        # Celery's words: "Refusing to deserialize untrusted content of type pickle
        # (application/x-python-serialize) ... The message has been ignored and discarded."
        return "Refusing to deserialize untrusted content of type pickle" in \
            farm.log.read_text()[len(log_before):]

    wait_until(refused, 60, "the worker to refuse the pickle message")
    assert not marker.exists()
    assert farm.proc.poll() is None, "the worker died"
    # The worker still renders: a JSON task after the refused one completes.
    r = farm_client.post("/api/jobs", json={"scene": tiny_scene})
    job = wait_for_job(farm_client, r.json()["id"])
    assert job["status"] == "done"
    assert not marker.exists()
