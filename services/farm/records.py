"""Job records: every job the farm was given, one row each in SQL, for as long as it is kept.

Redis holds what is in flight (the queue, the jobs not finished and their accumulations:
``services.farm.store``); this database holds the history. A row is written when the job is
submitted (before Redis gets it), brought up to date from Redis while the job runs
(``Records.sync``, by the service's sweeper and before each listing), and completed when the job
is archived: its image in the blob store, its Redis keys removed (``services.farm.archive``).
Listing, filtering by status and paging happen here, on indexes.

=====================  ========================================================================
Column                 What
=====================  ========================================================================
``id``                 the job id (``uuid4().hex``)
``status``             ``queued`` / ``running`` / ``done`` / ``failed`` / ``cancelled``
plan summary           ``width``, ``height``, ``spp``, ``tile_size``, ``spp_per_pass``,
                       ``max_spp_per_pass``, ``tasks_total``
counters               ``tasks_merged``, ``samples_merged``, ``dropped``, ``version`` (merges)
timings                ``created_at``, ``started_at``, ``finished_at`` (Unix seconds)
``error``, ``methods`` the reason a job failed; what ``auto`` chose for each material (JSON)
``submitter``          the name of the API token it came with (``LUCENT_API_TOKENS``), if any
``tiles``              once archived: per tile samples per pixel and last error (JSON)
``image_exr/_png``     once archived: the image's blob keys (``sha256:…``)
``archived_at``        when its Redis keys were removed; NULL while Redis holds the job
``image_bytes``        bytes of its image in the blob store (EXR + PNG)
``image_removed_at``   when the cap on stored images (``LUCENT_MAX_IMAGE_BYTES``) removed it
``state_blob``         a failed or cancelled job parked out of Redis: the blob of its tiles'
                       accumulations (``JobSnapshot``), what a retry goes on from
``tags``               the worker tags it requires, comma-separated (``services.farm.pools``)
``frames``             its frames (``services.farm.frames``); NULL for one. Once archived,
                       ``tiles`` lists each frame's images (``frame_images``)
``pass_growth``        how its passes grow (``services.farm.planner``); NULL for 1
``request_key``        the ``Idempotency-Key`` it was submitted with, scoped to its submitter
                       (``request_key``; unique): a submission sent again finds this job
``request_digest``     the SHA-256 of that submission's body (the same key with another body
                       is refused)
``target_error``,      its ``render.target_error`` and the share of it ``auto``'s models may
``expected_bias``      take; whether its done image is denoised; the frames' expected relMSE
``denoise``,           from their samples' noise as its merges last left it (``JobMeta``'s; the
``expected_error``     job's listing gives them once it is out of Redis without ``tiles``)
=====================  ========================================================================

``job_counts`` holds the number of jobs of each status, kept by triggers on ``jobs`` (a listing's
total is one row, not a count of an index).

Backends: SQLite in the farm's data folder by default (Python's own ``sqlite3``: nothing to
install); PostgreSQL with ``DATABASE_URL=postgresql://...`` (driven by psycopg 3). The schema is
Alembic's (``services/farm/migrations``), upgraded at start-up by ``Records.migrate``: idempotent,
and serialized between processes that start together (a file lock beside the SQLite file, an
advisory lock on PostgreSQL).

An unreachable database is ``RecordsUnavailable`` (the API answers 503); workers never touch the
database, so passes render and merge in Redis through an outage, and the sweeper brings the rows
up to date once it answers again.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sqlalchemy import (
    BigInteger,
    Boolean,
    Column,
    Connection,
    Double,
    Engine,
    Index,
    Integer,
    MetaData,
    String,
    Table,
    Text,
    create_engine,
    delete,
    event,
    func,
    insert,
    or_,
    select,
    text,
    update,
)
from sqlalchemy import exc as sa_exc
from sqlalchemy.engine import make_url
from sqlalchemy.pool import NullPool

from services.farm.planner import Plan
from services.farm.store import ACTIVE, FINAL, JobMeta

MIGRATIONS = Path(__file__).resolve().parent / "migrations"

metadata = MetaData()

# The table as the newest migration leaves it (the migrations themselves do not import this).
jobs = Table(
    "jobs", metadata,
    Column("id", String(32), primary_key=True),
    Column("name", String(200), nullable=False),
    Column("status", String(16), nullable=False),
    Column("priority", Integer, nullable=False),
    Column("submitter", String(200)),
    *(Column(name, Integer, nullable=False)
      for name in ("width", "height", "spp", "tile_size", "spp_per_pass", "max_spp_per_pass",
                   "tasks_total", "tasks_merged")),
    Column("samples_merged", BigInteger, nullable=False),
    Column("dropped", BigInteger, nullable=False),
    Column("version", Integer, nullable=False),
    Column("created_at", Double, nullable=False),
    Column("started_at", Double),
    Column("finished_at", Double),
    Column("error", Text),
    Column("methods", Text, nullable=False),
    Column("tiles", Text),
    Column("image_exr", String(71)),
    Column("image_png", String(71)),
    Column("archived_at", Double),
    Column("image_bytes", BigInteger, nullable=False, server_default="0"),
    Column("image_removed_at", Double),
    Column("state_blob", String(71)),
    Column("tags", String(300)),
    Column("frames", Integer),
    Column("pass_growth", Integer),
    Column("request_key", String(64)),
    Column("request_digest", String(64)),
    Column("target_error", Double),
    Column("expected_error", Double),
    Column("expected_bias", Double),
    Column("denoise", Boolean),
    Index("jobs_created_at", "created_at", "id"),
    Index("jobs_status_created_at", "status", "created_at", "id"),
    Index("jobs_finished_at", "finished_at"),
    Index("jobs_image_exr", "image_exr"),
    Index("jobs_image_png", "image_png"),
    Index("jobs_state_blob", "state_blob"),
    Index("jobs_request_key", "request_key", unique=True),
)

# Jobs by status, kept by triggers on ``jobs`` (migration 0002).
job_counts = Table(
    "job_counts", metadata,
    Column("status", String(16), primary_key=True),
    Column("n", BigInteger, nullable=False),
)

# A listing's page reads everything but the per-tile JSON (kilobytes a job).
_LISTED = [c for c in jobs.c if c.name != "tiles"]

# What the database not answering looks like, whatever the driver: a refused or dropped
# connection, a file that cannot be opened, a pool with no connection to give.
_UNREACHABLE = (sa_exc.OperationalError, sa_exc.InterfaceError, sa_exc.TimeoutError)

# pg_advisory_xact_lock's key for migrations ("Lucent" in ASCII).
_MIGRATION_LOCK = 0x4C7563656E74

# A row queued or running whose job Redis does not hold, this long after it was created, is a
# job whose in-flight state Redis lost (a restart without persistence): it is marked failed. The
# delay covers a submission between its row's insert and its Redis keys (milliseconds; should
# Redis take longer, the row follows the job again at the next sweep: rows not archived are
# brought up to date from Redis).
LOST_AFTER = 10.0


class RecordsUnavailable(RuntimeError):
    """The job database does not answer (the API turns it into 503)."""


@dataclass(frozen=True)
class Submission:
    """What a job's row keeps of the request that made it, when that request had an
    ``Idempotency-Key``: the key as stored (``request_key``) and the SHA-256 of its body."""

    key: str
    digest: str


def request_key(submitter: str | None, key: str) -> str:
    """The stored form of an ``Idempotency-Key``: the SHA-256 of its submitter's name (the API
    token's, or none) and the key, so that one client's key never finds another's job."""
    return hashlib.sha256(f"{submitter or ''}\x00{key}".encode()).hexdigest()


def engine_for(url: str, schema: str | None = None) -> Engine:
    """An engine for ``url``; ``postgresql://`` means psycopg 3. SQLite gets a connection per
    use (no pool: a database file that went away is seen at once), write-ahead logging (readers
    never wait for the writer) and a busy timeout (API processes write one at a time)."""
    u = make_url(url)
    if u.drivername in ("postgresql", "postgres"):
        u = u.set(drivername="postgresql+psycopg")
    if u.get_backend_name() == "sqlite":
        if u.database and u.database != ":memory:":
            Path(u.database).parent.mkdir(parents=True, exist_ok=True)
        engine = create_engine(u, poolclass=NullPool)

        @event.listens_for(engine, "connect")
        def _pragmas(dbapi_connection: Any, _record: Any) -> None:
            cursor = dbapi_connection.cursor()
            cursor.execute("PRAGMA journal_mode=WAL")
            cursor.execute("PRAGMA synchronous=NORMAL")
            cursor.execute("PRAGMA busy_timeout=10000")
            cursor.close()

        return engine
    connect_args: dict[str, Any] = {}
    if u.get_backend_name() == "postgresql":
        # A server that stops answering fails a query within seconds, not at TCP's retry limit
        connect_args = {"connect_timeout": 5, "tcp_user_timeout": 10_000}
        if schema:
            connect_args["options"] = f"-csearch_path={schema}"
    return create_engine(u, pool_pre_ping=True, pool_timeout=10, connect_args=connect_args)


@dataclass(frozen=True)
class Tracked:
    """What ``sync`` last wrote of a job: it writes again only when this changes."""

    status: str
    version: int
    started_at: float | None
    finished_at: float | None
    error: str | None


class Records:
    """The ``jobs`` table. Thread-safe (an engine per process, a connection per call)."""

    def __init__(self, url: str, schema: str | None = None):
        self.engine = engine_for(url, schema)
        self.schema = schema if self.engine.dialect.name == "postgresql" else None
        self.where = self.engine.url.render_as_string(hide_password=True)
        self._synced: dict[str, Tracked] = {}
        self._lock = threading.Lock()

    @contextlib.contextmanager
    def _begin(self) -> Iterator[Connection]:
        try:
            with self.engine.begin() as conn:
                yield conn
        except _UNREACHABLE as err:
            reason = str(getattr(err, "orig", None) or err).strip().splitlines()[0]
            raise RecordsUnavailable(
                f"the job database ({self.engine.dialect.name}) is unavailable: {reason}"
            ) from err

    # --- the schema -----------------------------------------------------------------------------
    def migrate(self, target: str = "head") -> None:
        """Upgrade the schema to ``target`` (the newest migration); does nothing when it is
        there already."""
        from alembic import command
        from alembic.config import Config

        config = Config()
        config.set_main_option("script_location", str(MIGRATIONS))
        with self._migration_lock(), self._begin() as conn:
            if self.engine.dialect.name == "postgresql":
                conn.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": _MIGRATION_LOCK})
                if self.schema:
                    conn.execute(text(f'CREATE SCHEMA IF NOT EXISTS "{self.schema}"'))
            config.attributes["connection"] = conn
            command.upgrade(config, target)

    @contextlib.contextmanager
    def _migration_lock(self) -> Iterator[None]:
        """SQLite: an exclusive lock on ``<database>.migrate-lock`` (two processes upgrading one
        file would both try to create the tables)."""
        path = self.engine.url.database
        if self.engine.dialect.name != "sqlite" or not path or path == ":memory:":
            yield
            return
        with open(f"{path}.migrate-lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(lock, fcntl.LOCK_UN)

    def revision(self) -> str | None:
        """The schema's migration (Alembic's version table), None before the first."""
        from alembic.runtime.migration import MigrationContext

        with self._begin() as conn:
            return MigrationContext.configure(conn).get_current_revision()

    def ping(self) -> None:
        with self._begin() as conn:
            conn.execute(select(1))

    def close(self) -> None:
        self.engine.dispose()

    # --- one job --------------------------------------------------------------------------------
    def create(self, meta: JobMeta,
               submission: Submission | None = None) -> tuple[JobMeta, str] | None:
        """The row of a job just submitted (IntegrityError suppressed: adopted meanwhile). With
        a ``submission``, whose key another job's row may hold already (the same request sent
        again, perhaps at the same moment): that job and its request's digest, and no row
        written; else None."""
        values = _row(meta)
        if submission is not None:
            values.update(request_key=submission.key, request_digest=submission.digest)
        try:
            with self._begin() as conn:
                conn.execute(insert(jobs).values(**values))
        except sa_exc.IntegrityError:
            if submission is None:
                return None
            # the key's row (another job's), or this id's (adopted meanwhile, without a key)
            prior = self.by_request(submission.key)
            return prior if prior is not None and prior[0].id != meta.id else None
        return None

    def by_request(self, key: str) -> tuple[JobMeta, str] | None:
        """The job submitted with this request key (``request_key``), and its request's body
        digest; None if none has it (or its row was deleted)."""
        with self._begin() as conn:
            row = conn.execute(select(jobs).where(jobs.c.request_key == key)).mappings().first()
        return (_meta(row), row["request_digest"]) if row is not None else None

    def create_many(self, metas: list[JobMeta]) -> None:
        """Rows for many jobs at once, in one transaction (an import, a benchmark)."""
        with self._begin() as conn:
            conn.execute(insert(jobs), [_row(m) for m in metas])

    def get(self, job_id: str) -> JobMeta | None:
        with self._begin() as conn:
            row = conn.execute(select(jobs).where(jobs.c.id == job_id)).mappings().first()
        return _meta(row) if row is not None else None

    def delete(self, job_id: str) -> dict[str, str] | None:
        """Delete the row; the blob keys it named (``exr``, ``png``, ``state`` -> key), or None
        when there was no row. The keys are those of the row deleted: an archive that landed
        meanwhile is seen."""
        with self._begin() as conn:
            row = conn.execute(delete(jobs).where(jobs.c.id == job_id)
                               .returning(jobs.c.image_exr, jobs.c.image_png,
                                          jobs.c.state_blob, jobs.c.tiles)).first()
        with self._lock:
            self._synced.pop(job_id, None)
        if row is None:
            return None
        keys = {name: key for name, key in zip(("exr", "png", "state"), row[:3], strict=True)
                if key}
        # a job of frames: each frame's images (``frame{i}.exr``, ``frame{i}.png``)
        for i, images in enumerate(json.loads(row[3]).get("frame_images", []) if row[3] else []):
            keys.update({f"frame{i}.{fmt}": key for fmt, key in images.items()})
        return keys

    def blob_in_use(self, key: str) -> bool:
        """Whether a job's image is this blob (a frame's images are named in ``tiles``: that
        test reads every archived job of frames, without an index; it runs on deletions)."""
        with self._begin() as conn:
            return conn.scalar(select(jobs.c.id).where(
                or_(jobs.c.image_exr == key, jobs.c.image_png == key,
                    jobs.c.state_blob == key,
                    (jobs.c.frames > 1) & jobs.c.tiles.contains(key))).limit(1)) is not None

    # --- listing --------------------------------------------------------------------------------
    def page(self, status: str | None = None, offset: int = 0,
             limit: int = 50) -> tuple[list[JobMeta], int]:
        """Jobs newest first, filtered by status; returns (the page, how many match)."""
        query = select(*_LISTED).order_by(jobs.c.created_at.desc(), jobs.c.id.desc())
        count = select(func.coalesce(func.sum(job_counts.c.n), 0))
        if status is not None:
            query = query.where(jobs.c.status == status)
            count = count.where(job_counts.c.status == status)
        with self._begin() as conn:
            rows = conn.execute(query.offset(offset).limit(limit)).mappings().all()
            total = conn.scalar(count) or 0
        return [_meta(r) for r in rows], int(total)

    def count_by_status(self) -> dict[str, int]:
        with self._begin() as conn:
            return {status: int(n) for status, n in conn.execute(select(job_counts))}

    # --- jobs in flight -------------------------------------------------------------------------
    def sync(self, metas: list[JobMeta], adopt: bool = False) -> int:
        """Bring the rows of the jobs Redis holds up to date (status, counters, times, error),
        writing only those that changed since this process last wrote them. With ``adopt`` (at
        start-up), a job with no row (submitted before the farm kept records) gets one; without,
        it is left alone (its row was deleted meanwhile: it is not brought back). Returns the
        rows written."""
        with self._lock:
            changed = [m for m in metas if self._synced.get(m.id) != _tracked(m)]
        if not changed:
            return 0
        with self._begin() as conn:
            for m in changed:
                done = conn.execute(update(jobs).where(jobs.c.id == m.id,
                                                       jobs.c.archived_at.is_(None))
                                    .values(**_progress(m))).rowcount
                if not done and adopt and conn.scalar(
                        select(jobs.c.id).where(jobs.c.id == m.id)) is None:
                    conn.execute(insert(jobs).values(**_row(m)))
        with self._lock:
            live = {m.id for m in metas}
            self._synced = {k: v for k, v in self._synced.items() if k in live}
            self._synced.update({m.id: _tracked(m) for m in changed})
        return len(changed)

    def active_ids(self, created_before: float) -> list[str]:
        """Jobs queued or running by their rows, created before the time given."""
        with self._begin() as conn:
            return list(conn.scalars(select(jobs.c.id).where(
                jobs.c.status.in_(ACTIVE), jobs.c.created_at < created_before)))

    def mark_lost(self, job_ids: list[str], reason: str) -> int:
        """Fail jobs whose in-flight state Redis lost; returns how many."""
        if not job_ids:
            return 0
        with self._begin() as conn:
            return conn.execute(update(jobs).where(jobs.c.id.in_(job_ids),
                                                   jobs.c.status.in_(ACTIVE))
                                .values(status="failed", error=reason,
                                        finished_at=time.time())).rowcount

    # --- archived jobs --------------------------------------------------------------------------
    def archive(self, meta: JobMeta, images: dict[str, str], tiles: dict[str, Any],
                image_bytes: int = 0) -> bool:
        """The done job's last state, its image's blob keys and its tiles' summary; False if it
        has no row (deleted meanwhile: the caller removes what it stored) or is archived
        already. Only the first archive writes: two sweepers (``lucent up``'s two API processes)
        may archive a job at once, and the second can read the tiles' summary after the first
        has deleted the job from Redis (no samples, no ``expected_error``); written anyway, it
        replaced the first's in the record, and the done job's answer lost its error."""
        values = {**_progress(meta), "tiles": json.dumps(tiles), "archived_at": time.time(),
                  "image_exr": images.get("exr"), "image_png": images.get("png"),
                  "image_bytes": image_bytes}
        with self._begin() as conn:
            return conn.execute(update(jobs).where(jobs.c.id == meta.id,
                                                   jobs.c.archived_at.is_(None))
                                .values(**values)).rowcount > 0

    # --- failed and cancelled jobs out of Redis -------------------------------------------------
    def park(self, meta: JobMeta, state: str, tiles: dict[str, Any]) -> bool:
        """A failed or cancelled job's last state and the blob of its tiles (``state``); False
        if it has no row (deleted meanwhile)."""
        values = {**_progress(meta), "tiles": json.dumps(tiles), "archived_at": time.time(),
                  "state_blob": state}
        with self._begin() as conn:
            return conn.execute(update(jobs).where(jobs.c.id == meta.id)
                                .values(**values)).rowcount > 0

    def unpark(self, job_id: str) -> str | None:
        """The job is back in Redis: its row follows it again. The state blob it named."""
        with self._begin() as conn:
            state = conn.scalar(select(jobs.c.state_blob).where(jobs.c.id == job_id))
            conn.execute(update(jobs).where(jobs.c.id == job_id)
                         .values(archived_at=None, state_blob=None, tiles=None))
        with self._lock:
            self._synced.pop(job_id, None)
        return state

    # --- retention ------------------------------------------------------------------------------
    def finished_before(self, when: float, limit: int = 100) -> list[str]:
        """Up to ``limit`` finished jobs, oldest first, that finished before ``when``."""
        with self._begin() as conn:
            return list(conn.scalars(
                select(jobs.c.id).where(jobs.c.status.in_(FINAL), jobs.c.finished_at < when)
                .order_by(jobs.c.finished_at).limit(limit)))

    def images_over(self, cap: int) -> list[str]:
        """The jobs, oldest finished first, whose images must go for the rest to fit in ``cap``
        bytes."""
        with self._begin() as conn:
            excess = int(conn.scalar(select(func.coalesce(func.sum(jobs.c.image_bytes), 0)))
                         or 0) - cap
            out: list[str] = []
            if excess <= 0:
                return out
            rows = conn.execute(select(jobs.c.id, jobs.c.image_bytes)
                                .where(jobs.c.image_bytes > 0)
                                .order_by(jobs.c.finished_at, jobs.c.id))
            for job_id, size in rows:
                out.append(job_id)
                excess -= int(size)
                if excess <= 0:
                    break
            return out

    def remove_image(self, job_id: str) -> dict[str, str]:
        """Forget the job's image, every frame's of a job of frames (its record stays,
        ``image_removed_at`` set); the blob keys it named (the caller deletes those no other
        record names), {} when it had none."""
        with self._begin() as conn:
            row = conn.execute(select(jobs.c.image_exr, jobs.c.image_png, jobs.c.tiles)
                               .where(jobs.c.id == job_id, jobs.c.image_bytes > 0)).first()
            if row is None:
                return {}
            # a job of frames: its frames' images leave ``tiles`` too (blob_in_use reads them)
            tiles = json.loads(row[2]) if row[2] else None
            frame_images = tiles.pop("frame_images", []) if tiles is not None else []
            # only if it still names those blobs (a second sweeper, a deletion meanwhile)
            done = conn.execute(update(jobs).where(jobs.c.id == job_id,
                                                   jobs.c.image_exr == row[0],
                                                   jobs.c.image_bytes > 0)
                                .values(image_exr=None, image_png=None, image_bytes=0,
                                        tiles=json.dumps(tiles) if tiles is not None else None,
                                        image_removed_at=time.time())).rowcount
        if not done:
            return {}
        keys = {fmt: key for fmt, key in zip(("exr", "png"), row[:2], strict=True) if key}
        for i, images in enumerate(frame_images):
            keys.update({f"frame{i}.{fmt}": key for fmt, key in images.items()})
        return keys

    def set_finished_at(self, job_id: str, when: float) -> None:
        """Move a finished job's finishing time (an import, or a test of retention)."""
        with self._begin() as conn:
            conn.execute(update(jobs).where(jobs.c.id == job_id).values(finished_at=when))


def _tracked(meta: JobMeta) -> Tracked:
    return Tracked(meta.status, meta.version, meta.started_at, meta.finished_at, meta.error)


def _row(meta: JobMeta) -> dict[str, Any]:
    plan = meta.plan
    row = {"id": meta.id, "name": meta.name, "priority": meta.priority,
           "submitter": meta.submitter,
           "width": plan.width, "height": plan.height, "spp": plan.spp,
           "tile_size": plan.tile_size, "spp_per_pass": plan.spp_per_pass,
           "max_spp_per_pass": plan.max_spp_per_pass, "tasks_total": plan.n_tasks,
           "created_at": meta.created_at, "methods": json.dumps(meta.methods),
           **_progress(meta)}
    # (columns of migrations 0003 to 0005: a row without them is written as before those)
    if meta.tags:
        row["tags"] = ",".join(meta.tags)
    if plan.frames > 1:
        row["frames"] = plan.frames
    if plan.pass_growth != 1:
        row["pass_growth"] = plan.pass_growth
    if meta.images:  # archived before the farm kept records (the hash held the blob keys)
        row.update(tiles=json.dumps(meta.tiles_final), image_exr=meta.images.get("exr"),
                   image_png=meta.images.get("png"), archived_at=time.time())
    return row


def _progress(meta: JobMeta) -> dict[str, Any]:
    """What a row follows of its job while Redis holds it, and keeps of it once out: its
    status, counters, times and error, and where it has them its target and expected error
    (the columns of migration 0007: a job without them is written as before it)."""
    out = {"status": meta.status, "tasks_merged": meta.tasks_merged,
           "samples_merged": meta.samples_merged, "dropped": meta.dropped,
           "version": meta.version, "started_at": meta.started_at,
           "finished_at": meta.finished_at, "error": meta.error}
    errors = {"target_error": meta.target_error, "expected_error": meta.expected_error,
              "expected_bias": meta.expected_bias or None, "denoise": meta.denoise or None}
    out.update({name: value for name, value in errors.items() if value is not None})
    return out


def _meta(row: Any) -> JobMeta:
    images = {fmt: row[f"image_{fmt}"] for fmt in ("exr", "png") if row[f"image_{fmt}"]}
    tiles = row.get("tiles")
    final = json.loads(tiles) if tiles else {}

    def kept(name: str) -> Any:
        """A column of migration 0007, or where it is NULL (a row written before it and not
        since), the tiles' summary's (read with the row, not with a listing's page)."""
        value = row.get(name)
        return final.get(name) if value is None else value

    return JobMeta(
        id=row["id"], name=row["name"], status=row["status"], priority=row["priority"],
        plan=Plan(row["width"], row["height"], row["spp"], row["tile_size"],
                  row["spp_per_pass"], row["max_spp_per_pass"], row.get("frames") or 1,
                  row.get("pass_growth") or 1),
        tasks_merged=row["tasks_merged"], samples_merged=row["samples_merged"],
        dropped=row["dropped"], version=row["version"], created_at=row["created_at"],
        started_at=row["started_at"], finished_at=row["finished_at"], error=row["error"],
        methods=json.loads(row["methods"]), images=images,
        tiles_final=final, submitter=row["submitter"],
        image_removed=row["image_removed_at"] is not None, parked=row.get("state_blob"),
        tags=tuple(t for t in (row.get("tags") or "").split(",") if t),
        target_error=kept("target_error"), expected_bias=float(kept("expected_bias") or 0.0),
        denoise=bool(kept("denoise")), recorded_error=kept("expected_error"))
