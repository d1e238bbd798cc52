"""The Celery application: ``celery -A worker.celery_app worker``."""

from __future__ import annotations

from celery import Celery

app = Celery("lucent", include=["worker.tasks"])
app.config_from_object("worker.config")
