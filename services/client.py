"""A small client of the API: what ``lucent submit`` does (httpx)."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import httpx

IMAGE_TYPES = {".exr": "exr", ".png": "png", ".npy": "npy"}


def scene_for_upload(path: str | Path) -> dict[str, Any]:
    """Read a scene file; meshes given by ``path`` are read here and sent inline (the server never
    reads a path)."""
    path = Path(path)
    data = json.loads(path.read_text())
    for obj in data.get("objects", []):
        if isinstance(obj, dict) and obj.get("type") == "mesh" and obj.get("path"):
            from renderer.geometry.meshio import read_mesh

            mesh_path = Path(obj.pop("path")).expanduser()
            if not mesh_path.is_absolute():
                mesh_path = path.resolve().parent / mesh_path
            vertices, triangles = read_mesh(mesh_path)
            obj["vertices"] = vertices.tolist()
            obj["triangles"] = triangles.tolist()
    return data


class JobLost(RuntimeError):
    """The server no longer knows a job it accepted: it was deleted (``DELETE``, or the
    retention settings). A job whose Redis state was lost is answered, failed with the reason."""


class Client:
    def __init__(self, server: str, token: str | None = None, timeout: float = 60.0):
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.http = httpx.Client(base_url=server.rstrip("/"), headers=headers, timeout=timeout)

    def submit(self, scene: dict, **options: Any) -> dict:
        r = self.http.post("/api/jobs", json={"scene": scene, **options})
        if r.status_code == 422:
            raise ValueError("\n".join(
                f"{'.'.join(map(str, d['loc'][2:])) or d['loc']}: {d['msg']}"
                for d in r.json()["detail"]))
        r.raise_for_status()
        return r.json()

    def job(self, job_id: str) -> dict:
        r = self.http.get(f"/api/jobs/{job_id}")
        if r.status_code == 404:
            raise JobLost(f"job {job_id} is gone from the server (deleted)")
        r.raise_for_status()
        return r.json()

    def image(self, job_id: str, fmt: str) -> bytes:
        r = self.http.get(f"/api/jobs/{job_id}/image.{fmt}")
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
            while True:
                bar.update(job["samples_merged"] - bar.n)
                if job["status"] in ("done", "failed", "cancelled"):
                    return job
                time.sleep(interval)
                job = self.job(job_id)


def submit_and_wait(scene_path: str, server: str, *, token: str | None = None, wait: bool = False,
                    outputs: list[str] | None = None, quiet: bool = False,
                    options: dict[str, Any] | None = None) -> int:
    """``lucent submit``: returns the process exit code. ``outputs``: images to write when done."""
    outputs = outputs or []
    for output in outputs:
        if Path(output).suffix.lower() not in IMAGE_TYPES:
            print(f"{output}: unsupported image type (use .exr, .png or .npy)", file=sys.stderr)
            return 2
    client = Client(server, token)
    try:
        job = client.submit(scene_for_upload(scene_path), **(options or {}))
    except ValueError as err:
        print(f"{scene_path}: the server refused it:\n{err}", file=sys.stderr)
        return 1
    except httpx.HTTPError as err:
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
    except (JobLost, httpx.HTTPError) as err:
        print(f"{server}: {err}", file=sys.stderr)
        return 1
    if job["status"] != "done":
        print(f"job {job['id']} {job['status']}: {job.get('error') or ''}", file=sys.stderr)
        return 1
    print(f"job {job['id']} done in {time.perf_counter() - t0:.1f} s"
          + (f"; {job['dropped_samples']} non-finite samples dropped"
             if job["dropped_samples"] else ""), file=sys.stderr)
    for output in outputs:
        out = Path(output)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_bytes(client.image(job["id"], IMAGE_TYPES[out.suffix.lower()]))
        print(f"wrote {out}", file=sys.stderr)
    print(job["id"])
    return 0
