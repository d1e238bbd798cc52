"""The Celery application: ``celery -A worker.celery_app worker``."""

from __future__ import annotations

from celery import Celery

from worker import kombu_guard

# A worker keeps consuming after Redis drops its connection mid-task (see the module).
kombu_guard.install()

app = Celery("lucent", include=["worker.tasks"])
app.config_from_object("services.farm.celery_config")
