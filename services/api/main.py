"""The FastAPI application: ``uvicorn services.api.main:app`` or ``create_app(settings)``."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import Depends, FastAPI
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.cors import CORSMiddleware
from fastapi.staticfiles import StaticFiles

from renderer import __version__
from services.api.deps import require_token
from services.api.guards import (
    BodyLimit,
    database_unavailable,
    store_unavailable,
    validation_error,
)
from services.api.intake import Intake
from services.api.routes import assets, dashboard, health, jobs, workers
from services.farm.archive import chores, keep_records
from services.farm.availability import UNAVAILABLE
from services.farm.blobs import open_blob_store
from services.farm.merge import StallRule, Sweeper
from services.farm.queue import celery_client
from services.farm.records import Records, RecordsUnavailable
from services.farm.settings import Settings, get_settings
from services.farm.store import JobStore


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or get_settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        store = JobStore.from_url(settings.redis_url, settings.key_prefix)
        app.state.store = store
        # The job records: the schema migrated (idempotent), rows for the jobs Redis holds that
        # have none (a farm from before the records)
        records = Records(settings.database, settings.database_schema)
        records.migrate()
        keep_records(store, records, adopt=True)
        app.state.records = records
        app.state.status_views = jobs.StatusViews(store, records)
        app.state.celery = celery_client(settings)
        stall = StallRule(app.state.celery, settings.stall_timeout, settings.max_stall_requeues,
                          settings.stall_unheld_timeout)
        app.state.blobs = open_blob_store(settings.blob_location)
        sweeper = Sweeper(store, settings.sweep_interval, stall,
                          chores(store, records, app.state.blobs, settings.archive_done,
                                 settings.keep_days, settings.max_image_bytes,
                                 settings.park_after))
        sweeper.start()  # merges what a previous run or a lost worker left behind
        try:
            yield
        finally:
            sweeper.stop()
            app.state.intake.close()
            records.close()
            store.close()

    app = FastAPI(title="Lucent", version=__version__, lifespan=lifespan,
                  description="A render farm for physically based images of translucent things.")
    app.state.settings = settings
    app.state.intake = Intake(settings.intake_inline_bytes, settings.intake_processes,
                              settings.blob_location, settings.worker_kernel == "packet")
    # Read-only allow-lists for the dashboard, built once: requests name entries, never paths.
    app.state.examples = dashboard.find_examples()
    app.state.figures = dashboard.find_figures()

    app.add_middleware(BodyLimit, max_bytes=settings.max_body_bytes,
                       paths={"/api/assets": settings.max_asset_bytes})
    app.add_exception_handler(RequestValidationError, validation_error)
    for unavailable in UNAVAILABLE:
        app.add_exception_handler(unavailable, store_unavailable)
    app.add_exception_handler(RecordsUnavailable, database_unavailable)
    if settings.cors_origins:
        # Off unless configured: without Access-Control-Allow-Origin a browser keeps other sites'
        # pages from reading the API. No cookies are used (the token is a header), so no
        # credentials mode.
        app.add_middleware(CORSMiddleware, allow_origins=list(settings.cors_origins),
                           allow_methods=["GET", "POST", "DELETE"],
                           allow_headers=["Authorization", "Content-Type", "If-None-Match"],
                           expose_headers=["ETag"])

    api_deps = [Depends(require_token)]
    app.include_router(jobs.router, prefix="/api", dependencies=api_deps)
    app.include_router(workers.router, prefix="/api", dependencies=api_deps)
    app.include_router(assets.router, prefix="/api", dependencies=api_deps)
    app.include_router(dashboard.api_router, prefix="/api", dependencies=api_deps)
    app.include_router(health.router)
    app.include_router(health.metrics_router, dependencies=api_deps)
    # The dashboard: static files, no farm data in them (the pages call /api with the token).
    app.include_router(dashboard.page_router)
    app.mount("/dashboard", StaticFiles(directory=dashboard.STATIC_DIR), name="dashboard")
    return app


def __getattr__(name: str) -> FastAPI:
    # ``uvicorn services.api.main:app`` builds the app from the environment on first access.
    if name == "app":
        return create_app()
    raise AttributeError(name)
