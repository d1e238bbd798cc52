"""Celery configuration, in one module (Celery's docs' practice); values come from ``Settings``.

- JSON only: pickle would let anyone who can write to Redis run code on every worker.
- ``task_acks_late`` + ``worker_prefetch_multiplier = 1``: a task is acknowledged when it ends, and
  a worker holds one task at a time, so a worker that dies loses at most the pass it was rendering,
  and Redis hands that pass to another worker.
- ``task_reject_on_worker_lost``: a pool process killed mid-task (SIGKILL, out of memory) puts the
  task back at once. Celery itself does not cap how often; ``worker.tasks`` does, counting the
  deliveries of each (job, tile, pass) in Redis (``Settings.max_attempts``), so a scene that kills
  the tracer fails its job instead of looping.
- Time limits: soft (``SoftTimeLimitExceeded`` in the task, a failed try) then hard (the process is
  killed). ``visibility_timeout`` must exceed the hard limit (see ``services.farm.settings``).
  ``task_acks_on_timeout = False``: a pass killed by the hard limit goes back on the queue (its
  next delivery is a counted try). Celery's default acknowledges it as failed, and the pass, never
  merged, would leave its job running forever (a kernel stuck in numba never sees the soft limit:
  the signal is handled only when control returns to Python).
- Redelivery of a pass whose worker node vanished (its ack never comes): kombu looks for tasks
  unacknowledged for longer than ``visibility_timeout`` every ``unacked_restore_interval`` x
  ``unacked_restore_throttle`` seconds (default 10 x 10). Here every tenth of the visibility
  timeout, at most every 10 s, so a lost pass comes back within 1.1 x the timeout. A message the
  node took with it before kombu recorded it as unacknowledged (killed between ``BRPOP`` and
  ``QoS.append``) never comes back this way: the service's sweeper re-queues the unmerged passes
  of a job stalled for ``Settings.stall_timeout`` (``services.farm.merge.requeue_stalled``), which
  also brings back a dead node's passes before the visibility timeout.
- Worker pools: a node consumes the default queue and, with ``LUCENT_WORKER_TAGS``, the queue of
  every subset of its tags (``task_queues`` below; ``services.farm.pools``); a job's passes are
  sent to the queue of its tags.
- Priorities: Redis emulates them with one list per level; 0 is served first.
  ``services.farm.planner.celery_priority`` maps a job's priority 0–9 (9 most urgent) onto them.
"""

from __future__ import annotations

from typing import Any

from kombu import Exchange, Queue

from services.farm.pools import DEFAULT_QUEUE, worker_queues
from services.farm.settings import Settings, get_settings


def celery_config(settings: Settings) -> dict[str, Any]:
    """The settings below, for a given ``Settings`` (the service sends with the same ones)."""
    return {
        "broker_url": settings.redis_url,
        "broker_transport_options": {
            "visibility_timeout": settings.visibility_timeout,
            "priority_steps": list(range(10)),
            "sep": ":",
            "queue_order_strategy": "priority",
            "unacked_restore_interval": min(10.0, settings.visibility_timeout / 10),
            "unacked_restore_throttle": 1,
        },
        "task_soft_time_limit": settings.task_soft_time_limit,
        "task_time_limit": settings.task_time_limit,
        # As Celery creates a missing queue (a direct exchange of the queue's name), so that a
        # sender's queue and a worker's are the same
        "task_queues": [Queue(name, Exchange(name, "direct"), routing_key=name)
                        for name in worker_queues(settings.worker_tags)],
        "task_default_queue": DEFAULT_QUEUE,
    }


_conf = celery_config(get_settings())
broker_url = _conf["broker_url"]
broker_transport_options = _conf["broker_transport_options"]
task_soft_time_limit = _conf["task_soft_time_limit"]
task_time_limit = _conf["task_time_limit"]
task_queues = _conf["task_queues"]
task_default_queue = _conf["task_default_queue"]

broker_connection_retry_on_startup = True

# Results are written by the tasks themselves under deterministic keys: no result backend.
task_ignore_result = True

task_serializer = "json"
result_serializer = "json"
accept_content = ["json"]
event_serializer = "json"

task_acks_late = True
task_acks_on_timeout = False
worker_prefetch_multiplier = 1
task_reject_on_worker_lost = True
task_default_priority = 9
task_queue_max_priority = 10

# Pool processes warm the JIT in worker_process_init: a cached kernel loads in ~1.5 s. Celery's
# default 4 s would kill a replacement pool process (one started after another exited) while it
# does. Compiling afresh takes ~60 s on the 2-core development machine (docs/performance.md,
# "Start-up"), so a cold cache is filled once before the pool starts (worker.tasks, worker_init)
# rather than by each pool process, and a replacement loads the kernels instead of compiling.
worker_proc_alive_timeout = get_settings().proc_alive_timeout
worker_hijack_root_logger = False
worker_send_task_events = False
