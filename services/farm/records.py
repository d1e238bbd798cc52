"""Job records: every job the farm was given, one row each in SQL, for as long as it is kept.

Redis holds what is in flight (the queue, the accumulations of running jobs:
``services.farm.store``); this database holds the history. A row is written when the job is
submitted, brought up to date by the service's sweeper while the job runs, and completed when the
job is archived (its image in the blob store, its Redis keys removed: ``services.farm.archive``).
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
``tiles``              once archived: per tile state, samples per pixel and last error, and
                       the passes delivered more than once with their deliveries (JSON)
``archived_at``        when its Redis keys were removed; NULL while Redis holds the job
``image_bytes``        bytes of its image (and resumable state) in the blob store
``image_removed_at``   when the image cap (``LUCENT_MAX_IMAGE_BYTES``) removed its image
``pixel_samples_*``    at archive, the fewest and most samples (kept + dropped) of any pixel
=====================  ========================================================================

``job_counts`` holds the number of jobs of each status, kept by triggers on ``jobs``.

Backends: SQLite in the farm's data folder by default (Python's own ``sqlite3``: nothing to
install); PostgreSQL with ``DATABASE_URL=postgresql+psycopg://...`` (psycopg 3). The schema is
Alembic's (``services/farm/migrations``), upgraded at start-up by ``Records.migrate``: idempotent,
and serialized between processes that start together (a file lock beside the SQLite file, an
advisory lock on PostgreSQL).

An unreachable database is ``RecordsUnavailable`` (the API answers 503 naming it); workers never
touch the database, so passes render and merge in Redis through an outage.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sqlalchemy import (
    BigInteger,
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
    Column("archived_at", Double),
    Column("image_bytes", BigInteger, nullable=False),
    Column("image_removed_at", Double),
    Column("pixel_samples_min", Integer),
    Column("pixel_samples_max", Integer),
    Index("jobs_created_at", "created_at", "id"),
    Index("jobs_status_created_at", "status", "created_at", "id"),
    Index("jobs_finished_at", "finished_at"),
)

# Jobs by status, kept by triggers on ``jobs`` (migration 0002): a listing's total is one row.
job_counts = Table(
    "job_counts", metadata,
    Column("status", String(16), primary_key=True),
    Column("n", BigInteger, nullable=False),
)

# The page of a listing reads everything but the per-tile JSON (up to ~100 kB a job).
_LISTED = [c for c in jobs.c if c.name != "tiles"]

# What the database answering no longer looks like, whatever the driver: a refused or dropped
# connection, a file that cannot be opened, a pool with no connection to give.
_UNREACHABLE = (sa_exc.OperationalError, sa_exc.InterfaceError, sa_exc.TimeoutError)

# pg_advisory_xact_lock's key for migrations ("Lucent" in ASCII).
_MIGRATION_LOCK = 0x4C7563656E74


class RecordsUnavailable(RuntimeError):
    """The job database does not answer (the API turns it into 503)."""


@dataclass(frozen=True)
class JobRecord:
    """A job's row: the job as ``JobMeta`` and what only the database keeps."""

    meta: JobMeta
    archived_at: float | None
    image_bytes: int
    image_removed_at: float | None
    tiles: dict[str, Any] | None = None
    pixel_samples: tuple[int, int] | None = None


@dataclass(frozen=True)
class Archived:
    """What the archive adds to a finished job's row."""

    tiles: dict[str, Any]
    image_bytes: int
    pixel_samples: tuple[int, int]


def engine_for(url: str, schema: str | None = None) -> Engine:
    """An engine for ``url``: ``postgresql://`` means psycopg 3. SQLite gets a connection per
    use (no pool: a database file that went away is seen at once), write-ahead logging (readers
    never wait for the writer) and a busy timeout (API processes write one at a time)."""
    u = make_url(url)
    if u.drivername == "postgresql":
        u = u.set(drivername="postgresql+psycopg")
    if u.get_backend_name() == "sqlite":
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


class Records:
    """The ``jobs`` table. Thread-safe (an engine per process, a connection per call)."""

    def __init__(self, url: str, schema: str | None = None):
        self.engine = engine_for(url, schema)
        self.schema = schema if self.engine.dialect.name == "postgresql" else None
        self.where = self.engine.url.render_as_string(hide_password=True)

    @contextlib.contextmanager
    def _begin(self) -> Iterator[Connection]:
        try:
            with self.engine.begin() as conn:
                yield conn
        except _UNREACHABLE as err:
            reason = str(getattr(err, "orig", None) or err).strip().splitlines()[0]
            raise RecordsUnavailable(
                f"the job database ({self.where}) is unavailable: {reason}") from err

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
        file would both try to create the tables); the folder is made if missing."""
        path = self.engine.url.database
        if self.engine.dialect.name != "sqlite" or not path or path == ":memory:":
            yield
            return
        Path(path).parent.mkdir(parents=True, exist_ok=True)
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
    def create(self, meta: JobMeta) -> None:
        # IntegrityError: the row is there already (adopted by an API process starting up)
        with contextlib.suppress(sa_exc.IntegrityError), self._begin() as conn:
            conn.execute(insert(jobs).values(**_row(meta), image_bytes=0))

    def adopt(self, metas: list[JobMeta]) -> int:
        """Insert the jobs that have no row yet (jobs a farm had in Redis before it kept
        records); returns how many."""
        if not metas:
            return 0
        with self._begin() as conn:
            known = set(conn.scalars(select(jobs.c.id).where(
                jobs.c.id.in_([m.id for m in metas]))))
            rows = [{**_row(m), "image_bytes": 0} for m in metas if m.id not in known]
            if rows:
                conn.execute(insert(jobs), rows)
        return len(rows)

    def get(self, job_id: str) -> JobRecord | None:
        with self._begin() as conn:
            row = conn.execute(select(jobs).where(jobs.c.id == job_id)).mappings().first()
        return _record(row) if row is not None else None

    def delete(self, job_id: str) -> bool:
        with self._begin() as conn:
            return conn.execute(delete(jobs).where(jobs.c.id == job_id)).rowcount > 0

    # --- listing --------------------------------------------------------------------------------
    def page(self, status: str | None = None, offset: int = 0,
             limit: int = 50) -> tuple[list[JobRecord], int]:
        """Jobs newest first, filtered by status; returns (the page, how many match)."""
        query = select(*_LISTED).order_by(jobs.c.created_at.desc(), jobs.c.id.desc())
        count = select(func.coalesce(func.sum(job_counts.c.n), 0))
        if status is not None:
            query = query.where(jobs.c.status == status)
            count = count.where(job_counts.c.status == status)
        with self._begin() as conn:
            rows = conn.execute(query.offset(offset).limit(limit)).mappings().all()
            total = conn.scalar(count) or 0
        return [_record(r) for r in rows], int(total)

    def count_by_status(self) -> dict[str, int]:
        with self._begin() as conn:
            return {status: int(n) for status, n in conn.execute(select(job_counts))}

    # --- jobs in flight -------------------------------------------------------------------------
    def sync(self, metas: list[JobMeta]) -> None:
        """Bring the rows of jobs Redis holds up to date (status, counters, times, error)."""
        if not metas:
            return
        with self._begin() as conn:
            for m in metas:
                conn.execute(update(jobs).where(jobs.c.id == m.id,
                                                jobs.c.archived_at.is_(None))
                             .values(**_progress(m)))

    def unarchived_active(self) -> list[str]:
        """Jobs queued or running whose state Redis should hold."""
        with self._begin() as conn:
            return list(conn.scalars(select(jobs.c.id).where(
                jobs.c.status.in_(ACTIVE), jobs.c.archived_at.is_(None))))

    def mark_lost(self, job_ids: list[str], reason: str) -> int:
        """Fail jobs whose state Redis lost (restarted without persistence), unless they were
        archived meanwhile; returns how many."""
        if not job_ids:
            return 0
        now = time.time()
        with self._begin() as conn:
            return conn.execute(update(jobs).where(
                jobs.c.id.in_(job_ids), jobs.c.status.in_(ACTIVE), jobs.c.archived_at.is_(None),
            ).values(status="failed", error=reason, finished_at=now, archived_at=now)).rowcount

    # --- archived jobs --------------------------------------------------------------------------
    def archive(self, meta: JobMeta, archived: Archived) -> bool:
        """The finished job's last state and what the archive stored; False if it has no row
        (deleted meanwhile: the caller removes what it stored)."""
        values = {**_progress(meta), "tiles": json.dumps(archived.tiles),
                  "archived_at": time.time(), "image_bytes": archived.image_bytes,
                  "image_removed_at": None, "pixel_samples_min": archived.pixel_samples[0],
                  "pixel_samples_max": archived.pixel_samples[1]}
        with self._begin() as conn:
            return conn.execute(update(jobs).where(jobs.c.id == meta.id)
                                .values(**values)).rowcount > 0

    def reopen(self, job_id: str) -> bool:
        """A retried archived job is back in Redis, running: its row says so."""
        with self._begin() as conn:
            return conn.execute(update(jobs).where(
                jobs.c.id == job_id, jobs.c.status.in_(("failed", "cancelled")),
            ).values(status="running", error=None, finished_at=None, archived_at=None,
                     tiles=None, image_bytes=0, image_removed_at=None, pixel_samples_min=None,
                     pixel_samples_max=None)).rowcount > 0

    # --- retention ------------------------------------------------------------------------------
    def finished_before(self, when: float, limit: int = 500) -> list[str]:
        """Archived jobs that finished before ``when``, oldest first."""
        with self._begin() as conn:
            return list(conn.scalars(
                select(jobs.c.id).where(jobs.c.status.in_(FINAL), jobs.c.finished_at < when,
                                        jobs.c.archived_at.is_not(None))
                .order_by(jobs.c.finished_at).limit(limit)))

    def images_over(self, cap: int) -> list[str]:
        """The oldest jobs whose images must go for the rest to fit in ``cap`` bytes."""
        with self._begin() as conn:
            excess = int(conn.scalar(select(func.coalesce(func.sum(jobs.c.image_bytes), 0))) or 0)
            excess -= cap
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

    def image_removed(self, job_id: str) -> None:
        with self._begin() as conn:
            conn.execute(update(jobs).where(jobs.c.id == job_id)
                         .values(image_bytes=0, image_removed_at=time.time()))


def _row(meta: JobMeta) -> dict[str, Any]:
    plan = meta.plan
    return {"id": meta.id, "name": meta.name, "priority": meta.priority,
            "submitter": meta.submitter, "width": plan.width, "height": plan.height,
            "spp": plan.spp, "tile_size": plan.tile_size, "spp_per_pass": plan.spp_per_pass,
            "max_spp_per_pass": plan.max_spp_per_pass, "tasks_total": plan.n_tasks,
            "created_at": meta.created_at, "methods": json.dumps(meta.methods),
            **_progress(meta)}


def _progress(meta: JobMeta) -> dict[str, Any]:
    return {"status": meta.status, "tasks_merged": meta.tasks_merged,
            "samples_merged": meta.samples_merged, "dropped": meta.dropped,
            "version": meta.version, "started_at": meta.started_at,
            "finished_at": meta.finished_at, "error": meta.error}


def _record(row: Any) -> JobRecord:
    meta = JobMeta(
        id=row["id"], name=row["name"], status=row["status"], priority=row["priority"],
        plan=Plan(row["width"], row["height"], row["spp"], row["tile_size"],
                  row["spp_per_pass"], row["max_spp_per_pass"]),
        tasks_merged=row["tasks_merged"], samples_merged=row["samples_merged"],
        dropped=row["dropped"], version=row["version"], created_at=row["created_at"],
        started_at=row["started_at"], finished_at=row["finished_at"], error=row["error"],
        methods=json.loads(row["methods"]), submitter=row["submitter"])
    tiles = row.get("tiles")
    low, high = row["pixel_samples_min"], row["pixel_samples_max"]
    return JobRecord(meta=meta, archived_at=row["archived_at"], image_bytes=row["image_bytes"],
                     image_removed_at=row["image_removed_at"],
                     tiles=json.loads(tiles) if tiles else None,
                     pixel_samples=(low, high) if low is not None else None)
