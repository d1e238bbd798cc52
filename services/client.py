"""A small client of the API: what ``lucent submit`` does (httpx).

The farm can be unavailable for a while without anything being lost: its Redis restarting
(``lucent up`` restarts it; the API answers 503 meanwhile), the API process restarting (the
connection is refused). The client then asks again with growing delays (``RETRY_DELAYS``, at least
the server's ``Retry-After``), saying each time why, for up to ``patience`` seconds of
unavailability in a row; only then does it give up (``Unavailable``). Other errors end at once:
a 500 is a bug, and a 4xx will not change by asking again.
"""

from __future__ import annotations

import hashlib
import json
import sys
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx

IMAGE_TYPES = {".exr": "exr", ".png": "png", ".npy": "npy"}


def scene_for_upload(path: str | Path, client: Client) -> dict[str, Any]:
    """Read a scene file; each file it names by a path (relative to the scene's folder: a mesh's
    ``path``, the environment's ``image``, a bitmap texture's ``image``) is uploaded to the farm
    as an asset, unless the farm has it already (``HEAD`` first), and the reference rewritten to
    ``{"asset": "sha256:…"}`` (the server never reads a path)."""
    path = Path(path)
    data = json.loads(path.read_text())

    def upload(file: str) -> str:
        local = Path(file).expanduser()
        if not local.is_absolute():
            local = path.resolve().parent / local
        return client.upload_asset(local.read_bytes())

    for obj in data.get("objects", []):
        if isinstance(obj, dict) and obj.get("type") == "mesh" and obj.get("path"):
            obj["asset"] = upload(obj.pop("path"))
    env = data.get("environment")
    if isinstance(env, dict) and isinstance(env.get("image"), str) and env["image"]:
        env["image"] = {"asset": upload(env["image"])}
    for material in (data.get("materials") or {}).values():
        # Bitmap textures on any colour parameter (materials.NAME.albedo.image, ...)
        for value in material.values() if isinstance(material, dict) else ():
            if (isinstance(value, dict) and value.get("type") == "bitmap"
                    and isinstance(value.get("image"), str) and value["image"]):
                value["image"] = {"asset": upload(value["image"])}
    return data


class JobLost(RuntimeError):
    """The server no longer knows a job it accepted: it was deleted (``DELETE``, or the
    retention settings). A job whose in-flight state Redis lost is answered, failed with the
    reason."""


class Unavailable(RuntimeError):
    """The server stayed unavailable (503, 502, 504, or no connection) for longer than the
    client's patience; the message says the last reason."""


# Seconds between tries while the server is unavailable: doubling from half a second, then every
# 10 s (a restarted Redis is back within seconds; an API being redeployed within a minute).
RETRY_DELAYS = (0.5, 1.0, 2.0, 4.0, 8.0, 10.0)
UNAVAILABLE_STATUSES = (502, 503, 504)


def _stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


class Client:
    """``say``: where the client tells why it waits (stderr); ``patience``: seconds of
    unavailability in a row before it gives up."""

    def __init__(self, server: str, token: str | None = None, timeout: float = 60.0,
                 say: Callable[[str], None] = _stderr, patience: float = 600.0):
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.http = httpx.Client(base_url=server.rstrip("/"), headers=headers, timeout=timeout)
        self.say = say
        self.patience = patience

    def _request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        """The response, once the server is available; tries again with backoff meanwhile.

        A submission is sent again too, with the ``Idempotency-Key`` it was first sent with: a
        job it made already (its answer a 503 after the job was stored, or lost on the way) is
        the answer, not a second job. So a request with that header is sent again after a
        timeout too; another is not (a slow answer may still have done what it asked)."""
        tries = 0
        since = time.monotonic()
        keyed = "Idempotency-Key" in kwargs.get("headers", {})
        again: tuple[type[Exception], ...] = (httpx.ConnectError, httpx.RemoteProtocolError,
                                              httpx.ReadError)
        if keyed:
            again += (httpx.TimeoutException,)
        while True:
            try:
                r = self.http.request(method, path, **kwargs)
            except again as err:
                # Not sent, a connection the server closed as it went away, or (a request
                # that can be repeated) no answer in time
                why = f"cannot reach the server ({type(err).__name__}: {err})"
                retry_after = 0.0
            else:
                if r.status_code not in UNAVAILABLE_STATUSES:
                    return r
                why = f"{r.status_code} {_detail(r)}"
                retry_after = _seconds(r.headers.get("retry-after"))
            if time.monotonic() - since > self.patience:
                raise Unavailable(f"{method} {path}: the server was unavailable for more than "
                                  f"{self.patience:g} s; last: {why}")
            delay = max(RETRY_DELAYS[min(tries, len(RETRY_DELAYS) - 1)], retry_after)
            self.say(f"{method} {path}: {why}; retrying in {delay:g} s")
            time.sleep(delay)
            tries += 1

    def upload_asset(self, data: bytes) -> str:
        """The asset name of ``data`` on the farm, uploading it only if the farm lacks it."""
        digest = hashlib.sha256(data).hexdigest()
        if self._request("HEAD", f"/api/assets/{digest}").status_code == 200:
            return f"sha256:{digest}"
        r = self._request("POST", "/api/assets", content=data, params={"sha256": digest},
                          headers={"Content-Type": "application/octet-stream"})
        if r.status_code in (413, 422):
            raise ValueError(f"asset upload refused: {_detail(r)}")
        r.raise_for_status()
        return str(r.json()["asset"])

    def submit(self, scene: dict, **options: Any) -> dict:
        """Submit a job (one ``Idempotency-Key`` for all of this call's tries: one job)."""
        r = self._request("POST", "/api/jobs", json={"scene": scene, **options},
                          headers={"Idempotency-Key": uuid.uuid4().hex})
        if r.status_code == 422:
            raise ValueError("\n".join(
                f"{'.'.join(map(str, d['loc'][2:])) or d['loc']}: {d['msg']}"
                for d in r.json()["detail"]))
        r.raise_for_status()
        return r.json()

    def job(self, job_id: str) -> dict:
        r = self._request("GET", f"/api/jobs/{job_id}")
        if r.status_code == 404:
            raise JobLost(f"job {job_id} is gone from the server (deleted)")
        r.raise_for_status()
        return r.json()

    def image(self, job_id: str, fmt: str, frame: int | None = None) -> bytes:
        """The job's image, or with ``frame`` that frame's (a job of frames)."""
        where = f"frames/{frame}/" if frame is not None else ""
        r = self._request("GET", f"/api/jobs/{job_id}/{where}image.{fmt}")
        r.raise_for_status()
        return r.content

    def wait(self, job_id: str, progress: bool = True, interval: float = 0.25) -> dict:
        """Poll until the job is done, failed or cancelled, with a progress bar on stderr."""
        from tqdm import tqdm

        job = self.job(job_id)
        # a terminal redraws the bar in place; a log file (CI, `make demo > log`) gets a line a
        # refresh, so there it is refreshed every 10 s, not at every poll
        with tqdm(total=job["samples_planned"], unit="samples", unit_scale=True,
                  disable=not progress, file=sys.stderr, smoothing=0.3,
                  mininterval=0.1 if sys.stderr.isatty() else 10.0) as bar:
            say = self.say
            if say is _stderr:  # above the bar, not through it
                self.say = lambda line: bar.write(line, file=sys.stderr)
            try:
                while True:
                    bar.update(job["samples_merged"] - bar.n)
                    if job["status"] in ("done", "failed", "cancelled"):
                        return job
                    time.sleep(interval)
                    job = self.job(job_id)
            finally:
                self.say = say


def _detail(r: httpx.Response) -> str:
    try:
        detail = r.json().get("detail")
    except (ValueError, AttributeError):
        detail = None
    return detail if isinstance(detail, str) else r.reason_phrase


def _seconds(retry_after: str | None) -> float:
    """``Retry-After`` in seconds (its HTTP-date form is not used by the farm: 0)."""
    try:
        return min(max(float(retry_after or 0), 0.0), 60.0)
    except ValueError:
        return 0.0


def error_lines(job: dict[str, Any]) -> list[str]:
    """What ``lucent submit --wait`` says of a done job's error: its expected relMSE (the
    samples' estimate; none below 2 a pixel) against its target, and for a job of frames with a
    target each frame's, which the farm takes to the target on its own."""
    if job.get("expected_error") is None:
        return []
    target = job.get("target_error")
    bias = job.get("expected_bias") or 0.0  # (what auto's models may add: the job's answer)
    # (the farm stops a frame below its target: a done job above it ran into the cap)
    cap = (f"; above the target: a pixel takes at most render.spp, {job.get('spp')} samples, "
           "and more may reach it")
    parts = (f"; the samples' noise {job['expected_error'] - bias:.3g} and the bias of "
             f"auto's models, at most {bias:.3g}" if bias else "")
    frames = job.get("frame_progress") or []
    short = target is not None and job["expected_error"] > target
    lines = [f"expected relMSE {job['expected_error']:.3g}"
             + (", the frames' mean" if len(frames) > 1 else "")
             + (f" (target {target:g}{parts})" if target is not None else
                " (estimated from the samples' variance)")
             + (cap if short else "")]
    if target is not None and len(frames) > 1:
        for frame in frames:
            if frame.get("expected_error") is not None:
                error = frame["expected_error"]
                lines.append(f"frame {frame['index']}: expected relMSE {error:.3g}"
                             + (cap if error > target else ""))
    return lines


def submit_and_wait(scene_path: str, server: str, *, token: str | None = None, wait: bool = False,
                    outputs: list[str] | None = None, quiet: bool = False,
                    options: dict[str, Any] | None = None,
                    render: dict[str, Any] | None = None) -> int:
    """``lucent submit``: returns the process exit code. ``outputs``: images to write when done;
    ``render``: fields set in the scene's ``render`` before it is sent (``--target-error``)."""
    outputs = outputs or []
    for output in outputs:
        if Path(output).suffix.lower() not in IMAGE_TYPES:
            print(f"{output}: unsupported image type (use .exr, .png or .npy)", file=sys.stderr)
            return 2
    client = Client(server, token)
    try:
        scene = scene_for_upload(scene_path, client)
        if render and isinstance(scene.setdefault("render", {}), dict):
            # (a render that is not an object is left for the server to name)
            scene["render"].update(render)
        job = client.submit(scene, **(options or {}))
    except ValueError as err:
        print(f"{scene_path}: the server refused it:\n{err}", file=sys.stderr)
        return 1
    except (Unavailable, httpx.HTTPError) as err:
        print(f"{server}: {err}", file=sys.stderr)
        return 1
    print(f"job {job['id']}: {job['tiles']} tiles x {job['tasks_total'] // job['tiles']} passes "
          f"— {server.rstrip('/')}/#/job/{job['id']}", file=sys.stderr)
    if not (wait or outputs):
        print(job["id"])
        return 0
    t0 = time.perf_counter()
    try:
        job = client.wait(job["id"], progress=not quiet)
    except (JobLost, Unavailable, httpx.HTTPError) as err:
        print(f"{server}: {err}", file=sys.stderr)
        return 1
    if job["status"] != "done":
        print(f"job {job['id']} {job['status']}: {job.get('error') or ''}", file=sys.stderr)
        return 1
    print(f"job {job['id']} done in {time.perf_counter() - t0:.1f} s"
          + (f"; {job['dropped_samples']} non-finite samples dropped"
             if job["dropped_samples"] else ""), file=sys.stderr)
    for line in error_lines(job):
        print(line, file=sys.stderr)
    frames = job.get("frames", 1)
    for output in outputs:
        for frame in range(frames):
            # a job of frames: one numbered file a frame, out.png -> out_0000.png, out_0001.png
            out = numbered(Path(output), frame) if frames > 1 else Path(output)
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_bytes(client.image(job["id"], IMAGE_TYPES[out.suffix.lower()],
                                         frame if frames > 1 else None))
            print(f"wrote {out}", file=sys.stderr)
    print(job["id"])
    return 0


def numbered(path: Path, frame: int) -> Path:
    """``out.png`` -> ``out_0003.png`` for frame 3."""
    return path.with_name(f"{path.stem}_{frame:04d}{path.suffix}")


def sweep_values(text: str) -> list[Any]:
    """``1,2,4,8`` -> numbers; ``[1,0,0],[0,1,0]`` -> lists; ``diffusion,volumetric`` (not JSON)
    -> strings."""
    try:
        values = json.loads(f"[{text}]")
    except ValueError:
        values = [v.strip() for v in text.split(",")]
    if not values:
        raise ValueError("a sweep needs at least one value")
    return values
