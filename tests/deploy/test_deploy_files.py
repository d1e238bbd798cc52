"""The deploy files (deploy/) agree with the code: names, ports, probes, environment variables.

Docker and a cluster are not needed: every manifest is parsed and compared with ``Settings``,
the FastAPI app's routes and the Celery configuration.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

yaml = pytest.importorskip("yaml")

ROOT = Path(__file__).resolve().parents[2]
DEPLOY = ROOT / "deploy"
K8S = DEPLOY / "k8s"
YAML_FILES = sorted(DEPLOY.rglob("*.yaml"))
# Names the code reads outside Settings (searched for in the sources below).
CODE_DIRS = ("renderer", "services", "worker")


def load(path: Path) -> list[dict]:
    return [d for d in yaml.safe_load_all(path.read_text()) if d is not None]


def k8s_docs() -> list[dict]:
    kust = load(K8S / "kustomization.yaml")[0]
    return [d for name in kust["resources"] for d in load(K8S / name)]


def by_kind(kind: str, name: str | None = None) -> list[dict]:
    return [d for d in k8s_docs()
            if d["kind"] == kind and (name is None or d["metadata"]["name"] == name)]


def compose() -> dict:
    return load(DEPLOY / "compose.yaml")[0]


def container(deployment: str) -> dict:
    (dep,) = by_kind("Deployment", deployment)
    (c,) = dep["spec"]["template"]["spec"]["containers"]
    return c


def flag(argv: list[str], name: str) -> str:
    return argv[argv.index(name) + 1]


def settings_env_names() -> set[str]:
    from pydantic import AliasChoices

    from services.farm.settings import Settings

    prefix = Settings.model_config["env_prefix"]
    names = set()
    for field, info in Settings.model_fields.items():
        alias = info.validation_alias
        if isinstance(alias, AliasChoices):
            names |= {a.upper() for a in alias.choices if isinstance(a, str)}
        else:
            names.add((prefix + field).upper())
    return names


def code_text() -> str:
    return "\n".join(p.read_text() for d in CODE_DIRS for p in (ROOT / d).rglob("*.py"))


@pytest.mark.parametrize("path", YAML_FILES, ids=lambda p: str(p.relative_to(DEPLOY)))
def test_every_yaml_parses(path: Path) -> None:
    assert load(path), f"{path} is empty"


def test_kustomization_lists_every_manifest() -> None:
    kust = load(K8S / "kustomization.yaml")[0]
    listed = set(kust["resources"])
    on_disk = {p.name for p in K8S.glob("*.yaml")} - {"kustomization.yaml"}
    assert listed == on_disk


# --- environment ----------------------------------------------------------------------------------

def _lucent_envs() -> dict[str, dict[str, str | None]]:
    """Environment of every container that runs Lucent's code: {where: {name: value}}."""
    out: dict[str, dict[str, str | None]] = {}
    for svc in ("api", "worker"):
        out[f"compose/{svc}"] = dict(compose()["services"][svc]["environment"])
    for dep in by_kind("Deployment"):
        for c in dep["spec"]["template"]["spec"]["containers"]:
            if c["image"] == "lucent":
                out[f"k8s/{dep['metadata']['name']}"] = {
                    e["name"]: e.get("value") for e in c.get("env", [])}
    return out


def test_env_names_are_read_by_the_code() -> None:
    known = settings_env_names()
    code = code_text()
    for where, env in _lucent_envs().items():
        for name in env:
            if name in known or f'"{name}"' in code:
                continue
            # a helper variable, only used to build another (k8s dependent variables)
            used = any(f"$({name})" in (v or "") for v in env.values())
            assert used, f"{where}: {name} is neither a Settings field nor read by the code"


def test_envs_build_valid_settings(monkeypatch: pytest.MonkeyPatch) -> None:
    from services.farm.settings import Settings

    for where, env in _lucent_envs().items():
        for name in settings_env_names():
            monkeypatch.delenv(name, raising=False)
        for name, value in env.items():
            value = re.sub(r"\$\{[^}]*\}|\$\([^)]*\)", "x", value or "secret-from-a-secret")
            monkeypatch.setenv(name, value)
        s = Settings()
        assert s.redis_url.startswith("redis://:") and "@redis:6379/" in s.redis_url, where


def test_settings_env_names_include_the_documented_ones() -> None:
    names = settings_env_names()
    assert {"REDIS_URL", "LUCENT_API_TOKEN", "LUCENT_KEY_PREFIX",
            "LUCENT_VISIBILITY_TIMEOUT", "LUCENT_ENVIRONMENT"} <= names


# --- ports and probes -----------------------------------------------------------------------------

def test_api_ports_match_uvicorn() -> None:
    c = container("api")
    port = int(flag(c["command"], "--port"))
    assert c["command"][:2] == ["uvicorn", "services.api.main:app"]
    (p,) = c["ports"]
    assert p["containerPort"] == port
    (svc,) = by_kind("Service", "api")
    assert svc["spec"]["ports"][0]["targetPort"] in (p["name"], port)
    assert svc["spec"]["selector"].items() <= by_kind("Deployment", "api")[0]["spec"][
        "template"]["metadata"]["labels"].items()

    api = compose()["services"]["api"]
    cport = int(flag(api["command"], "--port"))
    assert [int(str(m).rsplit(":", 1)[1]) for m in api["ports"]] == [cport]
    assert f":{cport}/healthz" in " ".join(api["healthcheck"]["test"])

    dockerfile = (DEPLOY / "Dockerfile").read_text()
    cmd = re.search(r"^CMD (\[.*\])$", dockerfile, re.M)
    assert cmd, "no exec-form CMD"
    argv = yaml.safe_load(cmd.group(1))
    assert argv[:2] == ["uvicorn", "services.api.main:app"]
    assert re.search(rf"^EXPOSE {int(flag(argv, '--port'))}$", dockerfile, re.M)


def app_paths() -> set[str]:
    """The GET paths of the FastAPI app (from its OpenAPI schema: included routers are nested)."""
    from services.api.main import create_app
    from services.farm.settings import Settings

    schema = create_app(Settings()).openapi()
    return {path for path, ops in schema["paths"].items() if "get" in ops}


def test_liveness_path_answers_without_redis() -> None:
    from fastapi.testclient import TestClient

    from services.api.main import create_app
    from services.farm.settings import Settings

    path = container("api")["livenessProbe"]["httpGet"]["path"]
    client = TestClient(create_app(Settings()))  # no `with`: no lifespan, no Redis
    assert client.get(path).json() == {"status": "ok"}


def test_probes_hit_existing_routes() -> None:
    paths = app_paths()
    c = container("api")
    assert c["livenessProbe"]["httpGet"]["path"] == "/healthz"
    assert c["readinessProbe"]["httpGet"]["path"] == "/readyz"
    for probe in ("livenessProbe", "readinessProbe"):
        get = c[probe]["httpGet"]
        assert get["path"] in paths
        assert get["port"] in ({p["name"] for p in c["ports"]} | {p["containerPort"]
                                                                   for p in c["ports"]})
    test = " ".join(compose()["services"]["api"]["healthcheck"]["test"])
    (path,) = re.findall(r"https?://[^/]+(/[^'\" ]*)", test)
    assert path in paths


# --- Celery queue and workers ---------------------------------------------------------------------

def celery_lists() -> set[str]:
    """The Redis lists of Celery's default queue: one per priority step, named as kombu does."""
    from worker.celery_app import app

    queue = app.conf.task_default_queue
    opts = app.conf.broker_transport_options
    return {f"{queue}{opts['sep']}{p}" if p else queue for p in opts["priority_steps"]}


def test_keda_watches_the_celery_queue() -> None:
    (so,) = by_kind("ScaledObject")
    assert so["spec"]["scaleTargetRef"]["name"] == "worker"
    triggers = so["spec"]["triggers"]
    assert all(t["type"] == "redis" for t in triggers)
    assert {t["metadata"]["listName"] for t in triggers} == celery_lists()
    assert "celery" in celery_lists()
    (auth,) = by_kind("TriggerAuthentication")
    assert all(t["authenticationRef"]["name"] == auth["metadata"]["name"] for t in triggers)
    (redis_svc,) = by_kind("Service", "redis")
    for t in triggers:
        host, port = t["metadata"]["address"].rsplit(":", 1)
        assert host.split(".")[0] == "redis" and int(port) == redis_svc["spec"]["ports"][0]["port"]


def test_worker_runs_celery_with_the_farm_defaults() -> None:
    from services.launcher import worker_command

    expected = worker_command(1)[worker_command(1).index("-A"):]
    c = container("worker")
    argv = c["command"]
    assert argv[0] == "celery"
    assert flag(argv, "-A") == flag(expected, "-A") and "worker" in argv
    assert flag(argv, "--pool") == "prefork"
    for f in ("--without-gossip", "--without-mingle", "--without-heartbeat"):
        assert f in argv
    res = c["resources"]
    assert {"cpu", "memory"} <= res["requests"].keys() and {"cpu", "memory"} <= res["limits"].keys()
    assert int(flag(argv, "--concurrency")) <= float(res["limits"]["cpu"])
    env = {e["name"]: e.get("value") for e in c["env"]}
    assert env["NUMBA_NUM_THREADS"] == "1"
    assert "ports" not in c

    w = compose()["services"]["worker"]
    wargv = shlex.split(w["command"][-1])
    assert wargv[:4] == ["exec", "celery", "-A", "worker.celery_app"]
    assert "ports" not in w and "container_name" not in w
    assert w["environment"]["NUMBA_NUM_THREADS"] == "1"


# --- Redis ----------------------------------------------------------------------------------------

def test_compose_redis_private_persistent_with_password() -> None:
    services = compose()["services"]
    r = services["redis"]
    assert "ports" not in r and "expose" not in r
    cmd = r["command"]
    assert flag(cmd, "--requirepass").startswith("${REDIS_PASSWORD:?")
    assert flag(cmd, "--appendonly") == "yes"
    assert any(v.endswith(":/data") for v in r["volumes"])
    for svc in ("api", "worker"):
        url = services[svc]["environment"]["REDIS_URL"]
        assert url.startswith("redis://:${REDIS_PASSWORD") and "@redis:6379/" in url
    assert services["flower"]["profiles"] == ["flower"]
    assert all("profiles" not in services[s] for s in ("redis", "api", "worker"))


def test_k8s_redis_password_from_secret() -> None:
    (sts,) = by_kind("StatefulSet", "redis")
    (c,) = sts["spec"]["template"]["spec"]["containers"]
    env = {e["name"]: e for e in c["env"]}
    ref = env["REDIS_PASSWORD"]["valueFrom"]["secretKeyRef"]
    assert flag(c["args"], "--requirepass") == "$(REDIS_PASSWORD)"
    assert flag(c["args"], "--appendonly") == "yes"
    (secret,) = by_kind("Secret", ref["name"])
    assert "REPLACE-ME" in secret["stringData"][ref["key"]]
    for dep in ("api", "worker"):
        denv = {e["name"]: e for e in container(dep)["env"]}
        assert denv["REDIS_PASSWORD"]["valueFrom"]["secretKeyRef"] == ref
        assert "$(REDIS_PASSWORD)@redis:" in denv["REDIS_URL"]["value"]
    token = {e["name"]: e for e in container("api")["env"]}["LUCENT_API_TOKEN"]
    assert token["valueFrom"]["secretKeyRef"]["name"] == ref["name"]


def _matches(selector: dict, labels: dict) -> bool:
    ok = selector.get("matchLabels", {}).items() <= labels.items()
    for expr in selector.get("matchExpressions", []):
        assert expr["operator"] == "In"
        ok = ok and labels.get(expr["key"]) in expr["values"]
    return ok


def _policy(name: str) -> dict:
    (pol,) = [p for p in by_kind("NetworkPolicy") if p["metadata"]["name"] == name]
    return pol


def test_networkpolicy_lets_only_the_api_reach_postgres() -> None:
    pol = _policy("postgres-api-only")
    pods = {d["metadata"]["name"]: d["spec"]["template"]["metadata"]["labels"]
            for d in by_kind("Deployment") + by_kind("StatefulSet")}
    assert {n for n, labels in pods.items()
            if _matches(pol["spec"]["podSelector"], labels)} == {"postgres"}
    peers = [p for rule in pol["spec"]["ingress"] for p in rule["from"]]
    assert all(set(p) == {"podSelector"} for p in peers)  # no other namespace, no address
    assert {n for n, labels in pods.items()
            if any(_matches(p["podSelector"], labels) for p in peers)} == {"api"}
    assert [p["port"] for rule in pol["spec"]["ingress"] for p in rule["ports"]] == [5432]


def test_networkpolicy_lets_only_api_and_workers_reach_redis() -> None:
    pol = _policy("redis-clients-only")
    pods = {d["metadata"]["name"]: d["spec"]["template"]["metadata"]["labels"]
            for d in by_kind("Deployment") + by_kind("StatefulSet")}
    selected = {n for n, labels in pods.items() if _matches(pol["spec"]["podSelector"], labels)}
    assert selected == {"redis"}
    assert pol["spec"]["policyTypes"] == ["Ingress"]
    in_namespace = [p for rule in pol["spec"]["ingress"] for p in rule["from"]
                    if "namespaceSelector" not in p and "ipBlock" not in p]
    allowed = {n for n, labels in pods.items() if any(_matches(p["podSelector"], labels)
                                                      for p in in_namespace)}
    assert allowed == {"api", "worker"}
    # the only other peer: KEDA's operator, in its own namespace, reading queue lengths
    others = [p for rule in pol["spec"]["ingress"] for p in rule["from"] if p not in in_namespace]
    for p in others:
        assert "ipBlock" not in p
        assert p["namespaceSelector"]["matchLabels"] == {"kubernetes.io/metadata.name": "keda"}
        assert p["podSelector"]["matchLabels"] == {"app": "keda-operator"}
    for rule in pol["spec"]["ingress"]:
        assert [p["port"] for p in rule["ports"]] == [6379]


# --- Dockerfile -----------------------------------------------------------------------------------

def test_dockerfile_multistage_nonroot_warm_cache() -> None:
    text = (DEPLOY / "Dockerfile").read_text()
    lines = [ln.strip() for ln in text.replace("\\\n", " ").splitlines()
             if ln.strip() and not ln.lstrip().startswith("#")]
    froms = [ln for ln in lines if ln.startswith("FROM ")]
    assert len(froms) >= 2 and any(ln.startswith("COPY --from=builder") for ln in lines)
    users = [ln.split()[1] for ln in lines if ln.startswith("USER ")]
    assert users, "no USER"
    user = users[-1].split(":")[0]
    assert user not in ("root", "0")
    after_user = lines[lines.index(f"USER {users[-1]}"):]
    # the workers' own warm-up (worker.runtime), which also marks the cache folder warm
    warm = [ln for ln in after_user if ln.startswith("RUN ") and "warm_up_kernels()" in ln]
    assert warm, "no cache-warming RUN as the runtime user"
    assert "from worker.runtime import warm_up_kernels" in warm[0]
    cache = re.search(r"LUCENT_CACHE_DIR=(\S+)", text).group(1)
    assert any(ln.startswith("RUN ") and "chown" in ln and cache in ln for ln in lines)
    # what the API serves from the source tree is in the image
    for path in ("examples", "services", "worker", "renderer"):
        assert any(ln.startswith(f"COPY {path} ") for ln in lines), path


def test_the_api_keeps_records_in_postgres_and_blobs_on_a_shared_volume() -> None:
    """Several API processes share the job database and the blob store (issue #20); the
    workers need neither."""
    services = compose()["services"]
    api = services["api"]
    assert api["environment"]["DATABASE_URL"].startswith(
        "postgresql+psycopg://lucent:${POSTGRES_PASSWORD:?")
    assert api["environment"]["LUCENT_DATA_DIR"] == "/data"
    assert "lucent-data:/data" in api["volumes"]
    assert "postgres" in api["depends_on"] and "ports" not in services["postgres"]
    assert "DATABASE_URL" not in services["worker"]["environment"]
    env = {e["name"]: e for e in container("api")["env"]}
    assert "$(POSTGRES_PASSWORD)@postgres:5432/" in env["DATABASE_URL"]["value"]
    assert "DATABASE_URL" not in {e["name"] for e in container("worker")["env"]}
    (pvc,) = by_kind("PersistentVolumeClaim", "lucent-data")
    assert pvc["spec"]["accessModes"] == ["ReadWriteMany"]
    (sts,) = by_kind("StatefulSet", "postgres")
    (c,) = sts["spec"]["template"]["spec"]["containers"]
    assert {e["name"]: e for e in c["env"]}["POSTGRES_PASSWORD"] == env["POSTGRES_PASSWORD"]
