"""The farm's settings, one ``Settings`` for the service and the workers (FastAPI template style).

Every field can be set from the environment: ``REDIS_URL`` as is, the others with the ``LUCENT_``
prefix (``LUCENT_API_TOKEN``, ``LUCENT_VISIBILITY_TIMEOUT``, ...). Scene size limits are the
renderer's own (``renderer.scene.Limits``, ``LUCENT_MAX_*``); the job limits here bound how a frame
may be cut up.

The timing settings must nest: a pass takes far less than ``task_soft_time_limit`` <
``task_time_limit`` < ``visibility_timeout``. Celery on Redis hands a task that was delivered but
not acknowledged to another worker once ``visibility_timeout`` has passed; with
``task_acks_late`` that clock runs from delivery to the end of the task, so a visibility timeout
shorter than the longest pass would deliver every long pass twice (harmless, as merging is exactly
once, but wasted work).

``stall_timeout`` must exceed ``task_time_limit`` too: the service's sweeper re-queues the
unmerged passes of a job that has had no pass start or merge for that long while none of its
passes can be waiting in Celery's queue. A message can be lost for good (a worker node killed
between Redis popping it and kombu recording it as unacknowledged, see ``services.farm.merge``); the
time limit bounds a pass still running, so a shorter stall time would re-run passes in progress.
Below ``visibility_timeout`` (the default) it also brings back, sooner, the passes of a worker
node that died as a whole.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Literal

from pydantic import AliasChoices, Field, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict


class Settings(BaseSettings):
    model_config = SettingsConfigDict(
        env_prefix="LUCENT_", extra="ignore", use_attribute_docstrings=True, frozen=True,
        populate_by_name=True,
    )

    environment: str = "development"
    """``development`` or ``production``; production refuses to run without an API token."""

    redis_url: str = Field(
        default="redis://127.0.0.1:6379/0",
        validation_alias=AliasChoices("REDIS_URL", "LUCENT_REDIS_URL"),
    )
    """Redis holds everything: the Celery broker, jobs, sample buffers and heartbeats."""

    key_prefix: str = "lucent"
    """Prefix of every key the farm writes (not Celery's own queue keys)."""

    api_token: str | None = None
    """When set, every ``/api`` route and ``/metrics`` need ``Authorization: Bearer <token>``."""

    api_tokens: Annotated[dict[str, str], NoDecode] = Field(default_factory=dict)
    """Named tokens, ``name:token`` comma-separated (``alice:s3cret,bob:0th3r``): each is accepted
    as ``LUCENT_API_TOKEN`` is, and a job submitted with one records its name as the submitter."""

    cors_origins: Annotated[list[str], NoDecode] = Field(default_factory=list)
    """Origins (``https://farm.example.org``) whose pages may call the API from a browser,
    comma-separated; empty (the default): no CORS headers, so only same-origin pages can."""

    # --- Job limits -----------------------------------------------------------------------------
    default_tile_size: int = Field(default=64, ge=8, le=1024)
    """Tile edge in pixels when a job does not say, halved for a frame that would have fewer than
    16 tiles (down to 16 px; ``services.farm.planner.default_tile_size``). A task costs ~6-8 ms
    besides rendering (Redis, the merge, Celery); a 64-px tile's first 8-sample pass is ~33 000
    paths, ~20 ms of one core on the Cornell box, so larger tiles keep that cost a small share:
    with two workers the Cornell box's job takes 2.0 s at 64 px against 2.8 s at 32 px
    (``python -m bench.scaling``, docs/performance.md)."""

    default_spp_per_pass: int = 8
    """Samples of a tile's first pass (the first preview)."""
    pass_growth: int = Field(default=2, ge=1, le=8)
    """Each pass after a tile's first holds this many times the samples before it, up to the
    largest pass (``services.farm.planner``): 2 gives 8, 16, 48, 64, … samples, every pass
    dividing the tile's noise variance by three; 1 gives 8, 8, 16, 32, 64, … (halving it), a
    task more per tile for the same samples. A job with a target error keeps 1: its tiles stop
    at the first pass that finds them converged, and larger steps overshoot the target. With two
    workers, the Cornell box's 64-spp job (20 tiles) runs 60 tasks instead of 80
    (docs/performance.md)."""
    default_max_spp_per_pass: int = Field(default=64, ge=1)
    """The largest pass when a job names none: passes grow up to it
    (``services.farm.planner``). 64 samples of a 64-px tile are ~260 000 paths, ~0.15 s of one
    core on the Cornell box: the ~6-8 ms a task costs besides rendering stays a small share."""

    packet_spp_per_pass: int = Field(default=32, ge=1)
    """The first pass of a job whose scene the packet kernel covers, when the workers render
    with it (``worker_kernel`` ``packet``, the default; the service reads the same setting, and
    where workers are live and none says it renders with it, ``services.farm.pools.
    packet_workers``, the scalar defaults stand): that kernel traces ~4 times as many
    paths a second as the scalar kernel (3.7x on the Cornell box), so 4 times the samples keep a
    task as long and the first preview as early as ``default_spp_per_pass`` on the scalar
    kernel. With the growth of 2 a 64-spp job runs 32 + 32 samples a tile (the 8, 16, 40 of the
    scalar default are 3 tasks a tile of 5-25 ms there; the ~4 ms a task costs besides rendering
    took a fifth of the farm's time: docs/performance.md)."""
    packet_max_spp_per_pass: int = Field(default=256, ge=1)
    """The largest pass of such a job when it names none: ``default_max_spp_per_pass`` times
    the same 4."""

    max_tasks_per_job: int = Field(default=200_000, ge=1)
    """The most (tile, pass) tasks one job may plan: bounds the queue and the bookkeeping."""

    max_body_bytes: int = Field(default=64 * 1024 * 1024, ge=1024)
    """The largest request body (HTTP 413 above it): inline meshes make scenes big."""

    max_asset_bytes: int = Field(default=512 * 1024 * 1024, ge=1024)
    """The largest asset ``POST /api/assets`` takes (HTTP 413 above it): a 1-million-triangle
    mesh is ~20 MB as binary PLY, ~60 MB as OBJ."""

    asset_cache_bytes: int = Field(default=2 * 1024**3, ge=0)
    """Workers: bytes of assets each keeps in its on-disk cache (``LUCENT_CACHE_DIR/assets``),
    least recently used removed first; 0: no cache (read from the blob store every time)."""

    intake_inline_bytes: int = Field(default=1024 * 1024, ge=0)
    """Submissions up to this size are parsed and checked in the API's thread pool; larger ones
    in a process of their own, so that parsing (which holds the GIL) never stalls the other
    routes (``services.api.intake``)."""

    intake_processes: int = Field(default=1, ge=1)
    """Processes that parse and check large submissions, one submission each at a time (a
    64 MB scene takes a few seconds and several hundred MB there)."""

    # --- Cost limits (``services.farm.cost``) -----------------------------------------------------
    max_samples_per_job: int = Field(default=2**34, ge=1)
    """The most pixel-samples (width x height x spp) one job may plan: 2^34 is a 4096² frame at
    1024 spp, about 1.7e10 camera paths (HTTP 422 on ``render.spp`` above it)."""

    max_queued_samples: int = Field(default=2**36, ge=1)
    """The most pixel-samples all queued and running jobs together may still have to render; a
    submission that would go over is refused with HTTP 429 until the backlog drains."""

    # --- Tasks ----------------------------------------------------------------------------------
    max_attempts: int = Field(default=3, ge=1)
    """Deliveries of one (tile, pass), redeliveries of a lost worker included, before the tile is
    marked failed: a scene that crashes the tracer fails its job instead of looping."""

    task_soft_time_limit: float = 300.0
    """Seconds before a pass is interrupted (``SoftTimeLimitExceeded``, counted as a failed try)."""

    task_time_limit: float = 360.0
    """Seconds before the process running a pass is killed."""

    visibility_timeout: float = 3600.0
    """Seconds after which Redis redelivers an unacknowledged task (see the module docstring)."""

    stall_timeout: float = 420.0
    """Seconds a queued or running job may go with no pass of it starting or merging, and none
    of its passes waiting in Celery's queue, before the sweeper re-queues its unmerged passes
    (a message lost by the broker; a worker node lost as a whole). Above ``task_time_limit``."""

    stall_unheld_timeout: float = Field(default=30.0, gt=0)
    """The stall time of a job none of whose passes a live worker process holds (records as
    rendering: ``JobStore.job_held``): nothing of it can be running, so there is no pass's time
    limit to wait for. A message stuck in kombu's ``unacked`` hash (its worker lost Redis, or
    died with it), or lost between ``BRPOP`` and kombu's record of it, comes back within this
    and a sweep. Used as at most ``stall_timeout``; above ``sweep_interval``."""

    max_stall_requeues: int = Field(default=3, ge=1)
    """Stall re-queues of one job in a row (no pass started or merged in between) before the job
    fails with the reason: a pass that is lost every time does not loop forever."""

    redis_outage_wait: float = Field(default=60.0, ge=0)
    """Seconds a worker process waits for Redis to come back when it goes away during a pass
    (restarted, a network cut), then runs the pass again from its start. Past it the message is
    given back: it stays in kombu's ``unacked`` hash, and comes back after the stall rule or the
    visibility timeout. The pass's own time limits still bound the wait."""

    heartbeat_interval: float = 2.0
    """Seconds between worker heartbeats; a worker silent for 3 intervals is shown as lost."""

    proc_alive_timeout: float = Field(default=120.0, gt=0)
    """Seconds a pool process started in place of one that exited has to load the renderer's
    kernels and report itself up (Celery's ``worker_proc_alive_timeout``: Celery kills one that
    is later; the pool's first processes are not timed)."""

    prewarm: bool = True
    """Compile a cold kernel cache once per worker node, before its pool starts
    (``worker.runtime.prewarm_cache``), so that the pool processes load the kernels instead of
    each compiling them."""

    pass_ttl: float = 7 * 24 * 3600.0
    """Seconds a pass buffer that was never merged is kept (a job's other keys have no TTL)."""

    compiled_cache_size: int = Field(default=4, ge=1)
    """Compiled scenes each worker process keeps (LRU by job id)."""

    sweep_interval: float = 1.0
    """Seconds between the service's sweeps: pass buffers left unmerged, jobs left unfinished,
    done jobs' images to the blob store, retention."""

    # --- Finished jobs (``services.farm.archive``) ----------------------------------------------
    data_dir: Path = Field(default_factory=lambda: Path(
        os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share") / "lucent")
    """The farm's data folder (the service's; workers write nothing there)."""

    database_url: str | None = Field(
        default=None, validation_alias=AliasChoices("DATABASE_URL", "LUCENT_DATABASE_URL"))
    """The job records' database (a SQLAlchemy URL): ``postgresql://user@host/db`` for a
    deployment (psycopg 3); unset, SQLite in ``data_dir`` (``lucent.db``: nothing to install)."""

    database_schema: str | None = Field(default=None, pattern=r"^[a-z_][a-z0-9_]{0,62}$")
    """PostgreSQL only: the schema of the farm's tables (created if missing), so that two farms
    (or test runs) can share one database, as ``key_prefix`` separates them in Redis."""

    blob_dir: Path | None = None
    """The blob store's folder, where done jobs' images are kept; default ``blobs`` in
    ``data_dir``. Every API process of one farm must see the same folder (a shared volume)."""

    blob_url: str | None = Field(default=None, pattern=r"^s3://")
    """The blob store in an S3-compatible bucket instead of a folder: ``s3://bucket/prefix``
    (boto3, the extra ``s3``; endpoint and credentials from boto3's environment,
    ``AWS_ENDPOINT_URL_S3``, ``AWS_ACCESS_KEY_ID``, ...). Unset: the folder ``blob_dir``."""

    archive_done: bool = True
    """Write each done job's image to the blob store and drop its accumulations from Redis;
    off (``LUCENT_ARCHIVE_DONE=0``), a done job's per-tile sample buffers stay in Redis, as
    before the blob store (to inspect every pixel's sample count)."""

    keep_days: float | None = Field(default=None, gt=0)
    """Days a finished (done, failed, cancelled) job is kept before the sweeper deletes it, keys
    and image; unset (the default): kept until ``DELETE /api/jobs/{id}``."""

    park_after: float | None = Field(default=600.0, ge=0)
    """Seconds after a job failed or was cancelled before the sweeper moves it out of Redis (its
    tiles' accumulations to the blob store, what a retry goes on from; its record keeps the
    rest). Unset: failed and cancelled jobs stay in Redis until deleted."""

    max_image_bytes: int | None = Field(default=None, ge=0)
    """The most bytes of finished jobs' images (EXR + PNG each) the blob store keeps; over it the
    sweeper removes the oldest (their records stay, their image routes answer 410). Unset: no
    cap."""

    worker_tags: Annotated[tuple[str, ...], NoDecode] = ()
    """This worker node's tags, comma-separated (``LUCENT_WORKER_TAGS=gpu,bigmem``): it takes
    the jobs that require no tags and those whose tags it has all of (``services.farm.pools``)."""

    worker_kernel: Literal["scalar", "wavefront", "gpu", "packet"] = "packet"
    """The kernel this worker node renders its passes with (``LUCENT_WORKER_KERNEL``, ``lucent
    worker --kernel``; ``renderer.render.render_tile``'s ``kernel``). ``gpu``: the wavefront
    stages on the node's CUDA GPU, for the scenes they cover (surface materials; the scalar kernel
    renders the rest); ``lucent worker --kernel gpu`` refuses to start where no GPU is seen. Tag
    such a node ``gpu`` (``--tags gpu``) so that jobs can ask for it. ``packet`` (the default,
    as for ``lucent render``, so that a farm's image is the local render's): 16 paths at once in
    the CPU's vector lanes for the scenes it covers (``renderer.packet``), the scalar kernel for
    the rest; ``scalar``: the scalar kernel for every scene."""

    blocklist_threshold: int = Field(default=3, ge=1)
    """Failed passes of one job on one worker node after which that node gets none of the job's
    passes any more (``services.farm.blocklist``)."""

    @property
    def database(self) -> str:
        """The job database's URL: ``DATABASE_URL``, else SQLite in the data folder."""
        return self.database_url or f"sqlite:///{self.data_dir / 'lucent.db'}"

    @property
    def blob_path(self) -> Path:
        return self.blob_dir if self.blob_dir is not None else self.data_dir / "blobs"

    @property
    def blob_location(self) -> str:
        """Where the blob store is, as ``open_blob_store`` takes it: the bucket, else the folder."""
        return self.blob_url or str(self.blob_path)

    @field_validator("api_tokens", mode="before")
    @classmethod
    def _split_tokens(cls, value: object) -> object:
        # LUCENT_API_TOKENS="alice:s3cret,bob:0th3r"
        if isinstance(value, str):
            pairs = [p.strip().partition(":") for p in value.split(",") if p.strip()]
            if any(not name.strip() or not token.strip() for name, _, token in pairs):
                raise ValueError("LUCENT_API_TOKENS is name:token, comma-separated")
            return {name.strip(): token.strip() for name, _, token in pairs}
        return value

    @field_validator("cors_origins", mode="before")
    @classmethod
    def _split_origins(cls, value: object) -> object:
        # LUCENT_CORS_ORIGINS="https://a.example,https://b.example"
        if isinstance(value, str):
            return [o.strip() for o in value.split(",") if o.strip()]
        return value

    @field_validator("worker_tags", mode="before")
    @classmethod
    def _split_tags(cls, value: object) -> object:
        from services.farm.pools import MAX_WORKER_TAGS, parse_tags

        tags = parse_tags(value) if isinstance(value, (str, list, tuple)) else value
        if isinstance(tags, tuple) and len(tags) > MAX_WORKER_TAGS:
            raise ValueError(f"a worker has at most {MAX_WORKER_TAGS} tags")
        return tags

    @model_validator(mode="after")
    def _check(self) -> Settings:
        if self.environment != "development" and not (self.api_token or self.api_tokens):
            raise ValueError("LUCENT_API_TOKEN must be set outside development")
        if not self.task_soft_time_limit < self.task_time_limit < self.visibility_timeout:
            raise ValueError(
                "need task_soft_time_limit < task_time_limit < visibility_timeout "
                f"(got {self.task_soft_time_limit}, {self.task_time_limit}, "
                f"{self.visibility_timeout})"
            )
        if not self.task_time_limit < self.stall_timeout:
            raise ValueError("need task_time_limit < stall_timeout (a running pass is not "
                             f"stalled; got {self.task_time_limit}, {self.stall_timeout})")
        if not self.sweep_interval < min(self.stall_timeout, self.stall_unheld_timeout):
            raise ValueError("need sweep_interval < stall_timeout and stall_unheld_timeout "
                             f"(got {self.sweep_interval}, {self.stall_timeout}, "
                             f"{self.stall_unheld_timeout})")
        return self


@lru_cache
def get_settings() -> Settings:
    """The process's settings, read from the environment once."""
    return Settings()
