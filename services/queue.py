"""Sending tasks: the service enqueues ``render_pass`` by name, so it never imports the renderer's
kernels (the API process stays light)."""

from __future__ import annotations

from celery import Celery

from services.planner import celery_priority
from services.settings import Settings

TASK = "worker.tasks.render_pass"


def celery_client(settings: Settings) -> Celery:
    """A Celery app with the workers' configuration for ``settings``, used only to send."""
    from worker.config import celery_config

    app = Celery("lucent")
    app.config_from_object("worker.config")
    app.conf.update(celery_config(settings))
    return app


def enqueue(app: Celery, job_id: str, tasks: list[tuple[int, int]], priority: int) -> None:
    """Send ``render_pass(job_id, tile, pass)`` for each pair, in the given order."""
    level = celery_priority(priority)
    with app.producer_or_acquire() as producer:
        for tile, pass_index in tasks:
            app.send_task(TASK, args=(job_id, tile, pass_index), priority=level,
                          producer=producer)
