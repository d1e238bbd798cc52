"""Hostile input: whatever a client sends, the API answers 4xx (naming the field where there is
one) and never 5xx, and nothing over a limit is queued.

- property-based fuzzing of every operation from the OpenAPI schema (schemathesis), bounded,
  with the classes of input that once reached a 500 mixed in (deep nesting, lone surrogates,
  integers past int64, non-finite numbers, in fields, query parameters and job ids);
- a test per such class (issue #24): nesting 500 deep in a request field, echoes of huge input,
  surrogates, integers past int64, an overflowing camera, float query parameters, job ids that
  name other keys, unknown fields, lax integers;
- bodies too big (declared or streamed), JSON nested 100 000 deep, malformed bytes;
- ``NaN``, ``Infinity`` and ``-Infinity`` (and ``1e400``) in every number of a scene and every
  field of the request;
- giant inline meshes, and scenes designed to be slow: 10⁶ spp, thousands of lights, a huge
  ``max_depth``, a giant film, and a job within every per-field limit but over the cost limits.
"""

from __future__ import annotations

import copy
import json
import math
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
import schemathesis
from fastapi import FastAPI
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from schemathesis.python.asgi import shutdown_lifespans

from renderer.film.buffer import SampleBuffer
from renderer.geometry.meshgen import sheet
from services.api.main import create_app
from services.farm.cost import queued_samples
from services.farm.planner import Plan, default_tile_size
from services.farm.settings import Settings
from services.farm.store import JobStore

ROOT = Path(__file__).resolve().parents[2]


def nested(depth: int, kind: str = "list") -> str:
    """JSON text: 1 inside ``depth`` lists or objects."""
    return ("[" * depth + "1" + "]" * depth if kind == "list"
            else '{"a": ' * depth + "1" + "}" * depth)


def leaves(value, path=()) -> Iterator[tuple]:
    """The path of every number and string in a JSON document."""
    if isinstance(value, dict):
        for k, v in value.items():
            yield from leaves(v, (*path, k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from leaves(v, (*path, i))
    else:
        yield path


def replaced(document: dict, path: tuple, value) -> dict:
    out = copy.deepcopy(document)
    target = out
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value
    return out


# --- fuzzing from the OpenAPI schema ------------------------------------------------------------

# Examples per operation, valid and invalid ones (schemathesis's positive and negative modes):
# the 13 operations take about 6 s here. The point is breadth on every run, not depth on one.
FUZZ_EXAMPLES = 100

# The schema is the app's own (building the app connects to nothing); the app that answers is
# built per module on the test Redis, without a token so that every operation is reached.
fuzzed = schemathesis.openapi.from_dict(
    create_app(Settings(redis_url="redis://127.0.0.1:1/0", environment="development",
                        api_token=None)).openapi())

# The schema says what is valid, and schemathesis's negative mode what breaks it, but neither
# makes the input classes that reached a 500 (issue #24). The hooks below mix them in: each
# generated body, query and job id is sent as generated or with one value made hostile.
# Bounded: nesting to 600 levels (below the parser's limit, where the echo used to recurse),
# texts of a few characters.
HOSTILE = st.one_of(
    # deep nesting
    st.tuples(st.integers(100, 600), st.sampled_from(["list", "object"])).map(
        lambda t: json.loads(nested(*t))),
    # lone UTF-16 surrogates, alone or inside a text
    st.builds(lambda a, s, b: a + s + b, st.text(max_size=3),
              st.characters(min_codepoint=0xD800, max_codepoint=0xDFFF), st.text(max_size=3)),
    # integers past int64
    st.integers(min_value=2**63, max_value=2**80), st.integers(max_value=-(2**63) - 1),
    st.sampled_from([2**63, 2**64, 10**100]),
    # numbers JSON has no literal for (Python's parser reads them, and 1e400 as inf)
    st.sampled_from([math.nan, math.inf, -math.inf]),
)
# The same as query strings: what a float or an int parameter may be sent as.
HOSTILE_QUERY = st.one_of(
    st.sampled_from(["nan", "NaN", "inf", "-inf", "Infinity", "1e400", "-1e400", "1e308",
                     "1024", "-1024", "0x10", "", "9" * 30, "-0", "1_000"]),
    st.floats().map(repr), st.integers(min_value=-(2**80), max_value=2**80).map(str))
# What a job id is followed by to name the job's other keys.
KEY_SUFFIXES = (":scene", ":merged", ":acc:0", ":tile_state", ":tile_samples", ":tile_error",
                ":attempts", ":pass:0:0", "")
REQUEST_FIELDS = ("name", "tile_size", "spp_per_pass", "max_spp_per_pass", "priority")


def fuzz_scene() -> dict:
    """A valid scene with every kind of value (a mesh's integer indices too), to make hostile."""
    scene = json.loads((ROOT / "examples" / "cornell_box.json").read_text())
    scene["film"] = {"width": 16, "height": 8}
    scene["render"]["spp"] = 1
    scene["objects"].append({"type": "mesh", "material": "white",
                             "vertices": [[0, 0, 0], [0.2, 0, 0], [0, 0.2, 0], [0, 0, 0.2]],
                             "triangles": [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]})
    return scene


FUZZ_SCENE = fuzz_scene()
FUZZ_SCENE_LEAVES = list(leaves(FUZZ_SCENE))
# A job of the fuzzed app's, every key of it present (filled in by fuzzed_app)
FUZZ_JOB: dict[str, str] = {}


def _hostile_body(body: dict, where: tuple, value) -> bytes:
    """The body with one request field, or one value of a valid scene, replaced by ``value``,
    as JSON text: non-finite floats as Python's literals, surrogates as their escapes."""
    out = dict(body)
    if where[0] == "field":
        out[where[1]] = value
    else:
        out["scene"] = replaced(FUZZ_SCENE, where[1], value)
    return json.dumps(out).encode()


@fuzzed.hook
def flatmap_body(ctx, body):
    if not isinstance(body, dict):
        return st.just(body)
    where = st.one_of(st.sampled_from(REQUEST_FIELDS + ("scene",)).map(lambda f: ("field", f)),
                      st.sampled_from(FUZZ_SCENE_LEAVES).map(lambda p: ("scene", p)))
    return st.one_of(st.just(body), st.builds(_hostile_body, st.just(body), where, HOSTILE))


@fuzzed.hook
def flatmap_query(ctx, query):
    names = sorted(p.name for p in ctx.operation.query)
    if not names or not isinstance(query, dict):
        return st.just(query)
    return st.one_of(st.just(query), st.builds(lambda name, value: {**query, name: value},
                                               st.sampled_from(names), HOSTILE_QUERY))


@fuzzed.hook
def flatmap_path_parameters(ctx, path_parameters):
    if not isinstance(path_parameters, dict) or "job_id" not in path_parameters:
        return st.just(path_parameters)
    # Read when the strategy draws, after fuzzed_app made the job
    real = st.sampled_from(KEY_SUFFIXES).map(lambda suffix: FUZZ_JOB["id"] + suffix)
    return st.one_of(st.just(path_parameters),
                     real.map(lambda job_id: {**path_parameters, "job_id": job_id}))


@pytest.fixture(scope="module")
def fuzzed_app(redis_base_url: str) -> Iterator[FastAPI]:
    own = Settings(redis_url=redis_base_url, environment="development", api_token=None,
                        key_prefix=f"lucent-test-fuzz-{uuid.uuid4().hex}")
    # A job with every key a job has, each of its own Redis type: an id followed by one of
    # KEY_SUFFIXES names them.
    store = JobStore.from_url(own.redis_url, own.key_prefix)
    job_id = uuid.uuid4().hex
    plan = Plan(16, 8, 2, 8, 1)
    store.create_job(job_id, "fuzz", 0, plan, json.dumps(FUZZ_SCENE))
    for tile in range(plan.n_tiles):
        store.put_pass(job_id, tile, 0, SampleBuffer.empty(8 * tile, 0, 8, 8).to_bytes(), 600)
        store.merge_pass_buffer(job_id, tile, 0)
    store.put_pass(job_id, 0, 1, SampleBuffer.empty(0, 0, 8, 8).to_bytes(), 600)
    store.add_attempt(job_id, 0, 1)
    store.note_tile_error(job_id, 0, "pass 1, try 1: fuzz")
    store.close()
    FUZZ_JOB["id"] = job_id
    yield create_app(own)
    shutdown_lifespans()  # schemathesis started the app's lifespan (its sweeper) on first call


@fuzzed.parametrize()
@settings(max_examples=FUZZ_EXAMPLES, deadline=None, database=None,
          suppress_health_check=list(HealthCheck))
def test_fuzzed_requests_never_get_a_5xx(case, fuzzed_app):
    response = case.call(app=fuzzed_app)
    if case.formatted_path == "/readyz" and response.status_code == 503:
        # no worker runs here: not ready, and saying why
        assert response.json()["reasons"] == [
            "no live workers: no worker process has sent a heartbeat within its timeout"]
        return
    assert response.status_code < 500, (case.method, case.formatted_path, response.text[:500])


# --- helpers ------------------------------------------------------------------------------------


def post_raw(client: TestClient, body: bytes | str, **kwargs):
    return client.post("/api/jobs", content=body, headers={"content-type": "application/json"},
                       **kwargs)


def locs(response) -> list[list]:
    return [d["loc"] for d in response.json()["detail"]]


def assert_nothing_queued(client: TestClient) -> None:
    assert client.get("/api/jobs").json()["count"] == 0
    assert client.get("/healthz").status_code == 200


def numeric_leaves(value, path=()) -> Iterator[tuple]:
    """The path of every number in a JSON document (booleans are not numbers)."""
    if isinstance(value, dict):
        for k, v in value.items():
            yield from numeric_leaves(v, (*path, k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from numeric_leaves(v, (*path, i))
    elif isinstance(value, int | float) and not isinstance(value, bool):
        yield path


# --- size and shape -----------------------------------------------------------------------------


@pytest.fixture
def small_body_client(settings: Settings) -> Iterator[TestClient]:
    small = settings.model_copy(update={"max_body_bytes": 64 * 1024})
    with TestClient(create_app(small)) as c:
        yield c


def test_a_huge_body_is_413_whether_declared_or_streamed(small_body_client, tiny_scene):
    huge = json.dumps({"scene": tiny_scene, "name": "x" * 100_000}).encode()
    r = post_raw(small_body_client, huge)  # Content-Length declared: refused before reading
    assert r.status_code == 413
    assert "LUCENT_MAX_BODY_BYTES" in r.json()["detail"]

    def chunks():  # no Content-Length: Transfer-Encoding: chunked
        for i in range(0, len(huge), 4096):
            yield huge[i:i + 4096]

    r = post_raw(small_body_client, chunks())
    assert r.status_code == 413
    assert "LUCENT_MAX_BODY_BYTES" in r.json()["detail"]
    # A streamed body under the limit still gets through to validation.
    r = post_raw(small_body_client, iter([json.dumps({"scene": tiny_scene}).encode()]))
    assert r.status_code == 201, r.text


@pytest.mark.parametrize("body", [
    '{"scene": {"a": ' + "[" * 100_000 + "]" * 100_000 + "}}",
    '{"scene": ' + '{"a": ' * 100_000 + "1" + "}" * 100_000 + "}",
    "[" * 100_000 + "]" * 100_000,
    '{"scene": {}, "name": ' + "[" * 100_000 + "]" * 100_000 + "}",
], ids=["array-in-scene", "objects-as-scene", "array-as-body", "array-as-name"])
def test_deeply_nested_json_is_a_4xx(client, body):
    r = post_raw(client, body)
    assert 400 <= r.status_code < 500, r.text[:300]
    assert_nothing_queued(client)


def test_nesting_inside_a_scene_is_422_naming_the_field(client, tiny_scene):
    deep: object = 1.0
    for _ in range(150):  # deep, but parseable: the scene models refuse it by its place
        deep = [deep]
    tiny_scene["camera"]["fov"] = deep
    r = client.post("/api/jobs", json={"scene": tiny_scene})
    assert r.status_code == 422
    assert locs(r) == [["body", "scene", "camera", "fov"]]


@pytest.mark.parametrize("body", [b'{"scene": "\xff\xfe"}', b"\x00\x01", b'{"scene": {}',
                                  b"", b"null", b"[]", b'"scene"', b"1e400"])
def test_malformed_bodies_are_a_4xx(client, body):
    r = post_raw(client, body)
    assert 400 <= r.status_code < 500, r.text[:300]
    assert_nothing_queued(client)


def test_huge_integers_are_a_4xx(client, tiny_scene):
    # Python refuses to parse integers over 4300 digits (a quadratic-time conversion).
    body = json.dumps({"scene": tiny_scene}).replace('"spp": 16', '"spp": ' + "9" * 5000)
    assert 400 <= post_raw(client, body).status_code < 500
    tiny_scene["render"]["spp"] = 10**100
    r = client.post("/api/jobs", json={"scene": tiny_scene})
    assert r.status_code == 422
    assert locs(r) == [["body", "scene", "render", "spp"]]


# --- non-finite numbers -------------------------------------------------------------------------


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "-Infinity"])
def test_non_finite_literals_anywhere_in_a_scene_are_422_naming_the_field(client, tiny_scene,
                                                                          literal):
    value = float(literal.replace("Infinity", "inf"))
    paths = list(numeric_leaves(tiny_scene))
    assert len(paths) > 50  # camera, film, render, materials, every object
    for path in paths:
        # json.dumps writes the non-standard literal itself: what a hostile client would send.
        r = post_raw(client, json.dumps({"scene": replaced(tiny_scene, path, value)}))
        assert r.status_code == 422, (path, r.status_code, r.text[:300])
        assert ["body", "scene", *path] in locs(r), (path, r.json())
    assert_nothing_queued(client)


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "-Infinity", "1e400"])
@pytest.mark.parametrize("field", ["name", "tile_size", "spp_per_pass", "priority"])
def test_non_finite_literals_in_the_request_are_422_naming_the_field(client, tiny_scene, field,
                                                                     literal):
    body = json.dumps({"scene": tiny_scene})[:-1] + f', "{field}": {literal}}}'
    r = post_raw(client, body)
    assert r.status_code == 422, r.text[:300]
    (detail,) = r.json()["detail"]
    assert detail["loc"] == ["body", field]
    # The echo of what was sent is itself valid JSON: the literal's name as a string.
    assert detail["input"] == ("Infinity" if literal == "1e400" else literal)


def test_non_finite_query_parameters_are_a_4xx(client):
    for exposure in ("nan", "inf", "-inf", "1e400"):
        r = client.get("/api/jobs/nope/image.png", params={"exposure": exposure})
        assert r.status_code in (404, 422), r.text
    for limit in ("nan", "inf", "1e400", "9" * 5000):
        assert client.get("/api/jobs", params={"limit": limit}).status_code == 422


# --- classes of input that answered 500 (issue #24) ----------------------------------------------

def with_field(scene: dict, field: str, raw_json: str) -> str:
    """The request body text with ``field`` set to ``raw_json`` (sent as written)."""
    return json.dumps({"scene": scene})[:-1] + f', "{field}": {raw_json}}}'


def assert_small_422(response, loc: list) -> dict:
    """A 422 naming ``loc`` whose reply stays small whatever was sent; returns its detail."""
    assert response.status_code == 422, response.text[:300]
    assert len(response.content) < 4096, len(response.content)
    (detail,) = response.json()["detail"]
    assert detail["loc"] == loc
    return detail


@pytest.mark.parametrize("kind", ["list", "object"])
@pytest.mark.parametrize("field", REQUEST_FIELDS)
def test_deep_nesting_in_a_request_field_is_422_naming_it(client, tiny_scene, field, kind):
    # 500 deep: parsed, then the 422's echo of it recursed past Python's limit (500 before).
    r = post_raw(client, with_field(tiny_scene, field, nested(500, kind)))
    detail = assert_small_422(r, ["body", field])
    assert "item" in json.dumps(detail["input"])  # echoed down to a summary of the rest
    # Past the parser's own limit: 400, as before.
    assert post_raw(client, with_field(tiny_scene, field, nested(10_000, kind))).status_code == 400
    assert_nothing_queued(client)


def test_a_422_echoes_a_bounded_part_of_the_input(client, tiny_scene):
    """The echo of a 5 MB name, a 100 000-item list and a 1 MB unknown field's name is cut:
    the reply is a few hundred bytes, not the size of the input."""
    r = client.post("/api/jobs", json={"scene": tiny_scene, "name": "x" * 5_000_000})
    detail = assert_small_422(r, ["body", "name"])
    assert detail["input"].startswith("xxxx") and "(5000000 characters)" in detail["input"]
    r = client.post("/api/jobs", json={"scene": tiny_scene, "tile_size": list(range(100_000))})
    detail = assert_small_422(r, ["body", "tile_size"])
    assert detail["input"][:3] == [0, 1, 2] and "99990 more items" in detail["input"][-1]
    r = client.post("/api/jobs", json={"scene": tiny_scene, "y" * 1_000_000: 1})
    detail = assert_small_422(r, ["body", "y" * 200 + "… (1000000 characters)"])
    assert_nothing_queued(client)


SURROGATE = "\ud800"  # a lone UTF-16 surrogate, as JSON escapes it


@pytest.mark.parametrize("where", ["name", "tile_size", "unknown field", "scene key",
                                   "scene string", "scene tag", "raw bytes"])
def test_lone_surrogates_are_422_naming_the_field(client, tiny_scene, where):
    """Python's JSON parser reads "\\ud800" (or its raw UTF-8 form) as a string that no UTF-8
    reply can hold: every str field refuses it, and the 422's echo escapes it."""
    body = {"scene": tiny_scene}
    if where in ("name", "tile_size"):
        body[where] = "a\ud800b"
        loc = ["body", where]
    elif where == "unknown field":  # a key that is no string: pydantic names the body
        body["\udc00"] = 1
        loc = ["body"]
    elif where == "scene key":
        tiny_scene["materials"]["\ud800"] = tiny_scene["materials"]["white"]
        loc = ["body", "scene", "materials"]
    elif where == "scene string":
        tiny_scene["objects"][0]["material"] = "\ud800"
        loc = ["body", "scene", "objects", 0, "material"]
    elif where == "scene tag":  # pydantic quotes it with U+FFFD in place of the surrogate
        tiny_scene["objects"][0]["type"] = "\ud800"
        loc = ["body", "scene", "objects", 0]
    if where == "raw bytes":  # the surrogate's UTF-8 form, which json.loads also decodes
        raw = json.dumps({"scene": tiny_scene, "name": "\ud800"}, ensure_ascii=False)
        r = post_raw(client, raw.encode("utf-8", "surrogatepass"))
        loc = ["body", "name"]
    else:
        r = post_raw(client, json.dumps(body))  # ensure_ascii: sent as the \ud800 escape
    assert r.status_code == 422, r.text[:300]
    r.content.decode("utf-8")  # strict UTF-8
    assert loc in locs(r), r.json()
    if where != "scene tag":
        assert "\\ud800" in r.text or "\\udc00" in r.text  # echoed escaped, as text
    assert_nothing_queued(client)


def test_integers_beyond_int64_are_422_naming_the_field(client, tiny_scene):
    """A triangle index of 2**63 reached numpy's int64 (OverflowError, 500). Every number of a
    scene with a mesh, set to integers past int64, is accepted or refused by name."""
    tet = {"type": "mesh", "material": "white",
           "vertices": [[0, 0, 0], [0.2, 0, 0], [0, 0.2, 0], [0, 0, 0.2]],
           "triangles": [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]}
    tiny_scene["objects"].append(tet)
    mesh = len(tiny_scene["objects"]) - 1
    r = client.post("/api/jobs", json={"scene": replaced(
        tiny_scene, ("objects", mesh, "triangles", 1, 2), 2**63)})
    assert locs(r) == [["body", "scene", "objects", mesh, "triangles", 1, 2]]
    for value in (2**63, -(2**63) - 1):
        for path in numeric_leaves(tiny_scene):
            r = client.post("/api/jobs", json={"scene": replaced(tiny_scene, path, value)})
            assert r.status_code in (201, 422), (path, value, r.status_code, r.text[:300])
            if r.status_code == 422:  # in the same entry (a vertex: its triangles, its mesh)
                entry = path[:2] if path[0] in ("objects", "lights", "materials") else path[:1]
                assert any(tuple(loc[2:2 + len(entry)]) == entry for loc in locs(r)), \
                    (path, value, r.json())
    for value in (2**63, -(2**63) - 1, 2**64, 10**30):
        for field in REQUEST_FIELDS[1:]:
            r = client.post("/api/jobs", json={"scene": tiny_scene, field: value})
            assert_small_422(r, ["body", field])


def test_a_camera_at_1e308_is_422_saying_it_overflows(client, tiny_scene):
    """Not "up is parallel to the viewing direction": the direction's length overflows."""
    tiny_scene["camera"]["position"] = [1e308, 1e308, 1e308]
    r = client.post("/api/jobs", json={"scene": tiny_scene})
    (detail,) = r.json()["detail"]
    assert detail["loc"] == ["body", "scene", "camera"]
    assert "overflows" in detail["msg"] and "parallel" not in detail["msg"]


@pytest.mark.parametrize("exposure", ["nan", "NaN", "inf", "-inf", "Infinity", "1e400",
                                      "-1e400", "1024", "-1024", "65", "1e308"])
def test_float_query_parameters_are_422_naming_them(client, tiny_scene, exposure):
    """On a real job (a 404 hid them before): non-finite, or past what 2**exposure holds."""
    job = client.post("/api/jobs", json={"scene": tiny_scene}).json()["id"]
    r = client.get(f"/api/jobs/{job}/image.png", params={"exposure": exposure})
    assert_small_422(r, ["query", "exposure"])
    for fine in ("-64", "-2.5", "0", "5", "64"):
        r = client.get(f"/api/jobs/{job}/image.png", params={"exposure": fine})
        assert r.status_code == 200, (fine, r.text[:300])


JOB_ROUTES = [("GET", "/api/jobs/{}"), ("GET", "/api/jobs/{}/image.png"),
              ("GET", "/api/jobs/{}/image.exr"), ("GET", "/api/jobs/{}/image.npy"),
              ("DELETE", "/api/jobs/{}"), ("POST", "/api/jobs/{}/retry")]


def test_job_ids_of_another_form_are_404_on_every_route(client, store, tiny_scene):
    """``<id>:scene`` named the job's other keys (WRONGTYPE, KeyError: 500). Every key of a job
    exists here, each of its own type."""
    job = client.post("/api/jobs", json={"scene": tiny_scene}).json()["id"]
    store.r.sadd(store.k("job", job, "merged"), "0:0")
    store.r.set(store.acc_key(job, 0), b"x")
    store.r.hset(store.k("job", job, "attempts"), "0:0", 1)
    store.r.hset(store.k("job", job, "tile_samples"), "0", 8)
    store.r.hset(store.k("job", job, "tile_error"), "0", "e")
    others = [f"{job}:{suffix}" for suffix in ("scene", "merged", "acc:0", "tile_state",
                                               "attempts", "tile_samples", "tile_error")]
    others += [job.upper(), job[:-1], job + "0", f"{job}%3Ascene", "*", "%2A", "x" * 10_000]
    for method, route in JOB_ROUTES:
        for other in others:
            r = client.request(method, route.format(other))
            assert r.status_code == 404, (method, route, other, r.status_code, r.text[:200])
            assert len(r.content) < 512
    assert client.get(f"/api/jobs/{job}").json()["status"] == "queued"  # untouched


def test_unknown_request_fields_are_422_naming_them(client, tiny_scene):
    """As in the scene: a typo is an error, not a silently ignored option."""
    for field in ("tilesize", "spp", "scene_", "Name"):
        r = client.post("/api/jobs", json={"scene": tiny_scene, field: 16})
        detail = assert_small_422(r, ["body", field])
        assert detail["msg"] == "unknown field"
    assert_nothing_queued(client)


@pytest.mark.parametrize("field", REQUEST_FIELDS[1:])
@pytest.mark.parametrize("value", ["8", 8.0, True, "0x8", [8]])  # 8: in every range
def test_request_level_integers_are_strict(client, tiny_scene, field, value):
    """As in the scene: a string or a float is not an integer (nor is true)."""
    r = client.post("/api/jobs", json={"scene": tiny_scene, field: value})
    assert_small_422(r, ["body", field])
    assert_nothing_queued(client)


def test_request_level_integers_are_accepted_as_integers(client, tiny_scene):
    r = client.post("/api/jobs", json={"scene": tiny_scene, "tile_size": 16, "spp_per_pass": 4,
                                       "max_spp_per_pass": 8, "priority": 1})
    assert r.status_code == 201, r.text
    assert (r.json()["tile_size"], r.json()["spp_per_pass"], r.json()["priority"]) == (16, 4, 1)


def test_a_job_without_a_tile_size_gets_the_default_for_its_frame(client, tiny_scene):
    """The default tile (64 px) halves until the frame has 16 tiles: the tiny scene's small frame
    gets 16-px tiles (services.farm.planner.default_tile_size)."""
    r = client.post("/api/jobs", json={"scene": tiny_scene})
    assert r.status_code == 201, r.text
    film = tiny_scene["film"]
    assert r.json()["tile_size"] == default_tile_size(film["width"], film["height"], 64) == 16


# --- giant meshes -------------------------------------------------------------------------------


def grid_mesh(n: int) -> dict:
    """An n x n grid of quads (2 n² triangles, (n + 1)² vertices): an open sheet."""
    vertices, triangles = sheet(n)
    return {"type": "mesh", "vertices": vertices.tolist(), "triangles": triangles.tolist(),
            "material": "white"}


def test_a_mesh_over_the_triangle_limit_is_refused_before_parsing(client, tiny_scene,
                                                                  monkeypatch):
    monkeypatch.setenv("LUCENT_MAX_TRIANGLES", "1000")
    tiny_scene["objects"].append(grid_mesh(23))  # 1058 triangles
    assert_refused_by_limit(client, tiny_scene, ["objects"], "LUCENT_MAX_TRIANGLES")
    tiny_scene["objects"][-1] = grid_mesh(22)  # 968 triangles: accepted
    assert client.post("/api/jobs", json={"scene": tiny_scene}).status_code == 201


def test_a_giant_mesh_is_capped_by_the_body_limit(small_body_client, tiny_scene):
    tiny_scene["objects"].append(grid_mesh(100))  # 20 000 triangles, ~0.5 MB of JSON
    r = small_body_client.post("/api/jobs", json={"scene": tiny_scene})
    assert r.status_code == 413
    assert small_body_client.get("/api/jobs").json()["count"] == 0


# --- scenes designed to be slow -----------------------------------------------------------------


def assert_refused_by_limit(client: TestClient, scene: dict, loc: list, variable: str) -> None:
    r = client.post("/api/jobs", json={"scene": scene})
    assert r.status_code == 422
    (detail,) = r.json()["detail"]
    assert detail["loc"] == ["body", "scene", *loc]
    assert variable in detail["msg"]
    assert_nothing_queued(client)


def test_a_million_spp_is_refused(client, tiny_scene):
    tiny_scene["render"]["spp"] = 1_000_000
    assert_refused_by_limit(client, tiny_scene, ["render", "spp"], "LUCENT_MAX_SPP")


def test_thousands_of_lights_are_refused(client, tiny_scene):
    light = {"type": "point", "position": [0, 0.9, 0], "intensity": [1, 1, 1]}
    tiny_scene["lights"] = [light] * 5000
    assert_refused_by_limit(client, tiny_scene, ["lights"], "LUCENT_MAX_LIGHTS")


def test_a_huge_max_depth_is_refused(client, tiny_scene):
    tiny_scene["render"]["max_depth"] = 10**9
    assert_refused_by_limit(client, tiny_scene, ["render", "max_depth"], "LUCENT_MAX_DEPTH")


def test_a_giant_film_is_refused(client, tiny_scene):
    tiny_scene["film"] = {"width": 1_000_000, "height": 1_000_000}
    r = client.post("/api/jobs", json={"scene": tiny_scene})
    assert r.status_code == 422
    assert {tuple(loc) for loc in locs(r)} >= {("body", "scene", "film", "width"),
                                               ("body", "scene", "film", "height")}


def test_a_job_within_every_field_limit_is_capped_by_its_cost(client, tiny_scene):
    """4096² pixels at 65 536 spp: every per-field limit allows it, the cost limit does not."""
    tiny_scene["film"] = {"width": 4096, "height": 4096}
    tiny_scene["render"]["spp"] = 65_536
    r = client.post("/api/jobs", json={"scene": tiny_scene, "tile_size": 1024,
                                       "spp_per_pass": 65_536})
    assert r.status_code == 422
    assert locs(r) == [["body", "scene", "render", "spp"], ["body", "scene", "film"]]
    assert "LUCENT_MAX_SAMPLES_PER_JOB" in r.json()["detail"][0]["msg"]
    assert_nothing_queued(client)


def test_the_per_job_cost_limit_is_exact(settings, tiny_scene):
    samples = 32 * 24 * 16  # the tiny scene's width x height x spp
    for limit, expected in ((samples, 201), (samples - 1, 422)):
        capped = settings.model_copy(update={"max_samples_per_job": limit,
                                             "key_prefix": f"{settings.key_prefix}-{limit}"})
        with TestClient(create_app(capped)) as c:
            r = c.post("/api/jobs", json={"scene": tiny_scene})
            assert r.status_code == expected, r.text
            if expected == 422:
                assert f"= {samples} pixel-samples exceed the limit {limit}" in r.text


def test_a_full_backlog_is_429_until_it_drains(settings, tiny_scene):
    samples = 32 * 24 * 16
    with TestClient(create_app(settings.model_copy(
            update={"max_queued_samples": 2 * samples}))) as c:
        first = c.post("/api/jobs", json={"scene": tiny_scene}).json()
        assert c.post("/api/jobs", json={"scene": tiny_scene}).status_code == 201
        r = c.post("/api/jobs", json={"scene": tiny_scene})
        assert r.status_code == 429
        assert r.headers["retry-after"] == "60"
        (detail,) = r.json()["detail"]
        assert detail["loc"] == ["body", "scene"]
        assert "LUCENT_MAX_QUEUED_SAMPLES" in detail["msg"]
        assert c.get("/api/jobs").json()["count"] == 2  # the refused job was not created
        # A cancelled job leaves the backlog: there is room again.
        assert c.delete(f"/api/jobs/{first['id']}").status_code == 200
        assert c.post("/api/jobs", json={"scene": tiny_scene}).status_code == 201


def test_the_backlog_counts_what_active_jobs_have_left(store):
    plan = Plan(width=10, height=10, spp=8, tile_size=8, spp_per_pass=4)  # 800 pixel-samples
    for job_id in ("queued", "running", "done", "cancelled"):
        store.create_job(job_id, "", 0, plan, "{}")
    store.r.hset(store.job_key("running"), mapping={"status": "running", "samples_merged": 300})
    store.r.hset(store.job_key("done"), mapping={"status": "done", "samples_merged": 800})
    store.cancel_job("cancelled")
    assert queued_samples(store) == 800 + 500
