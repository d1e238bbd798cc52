"""Keep a Celery worker consuming after its Redis connection drops while it holds messages.

kombu's Redis transport acknowledges, rejects and restores messages through the channel they
were delivered on. When Redis goes away (restarted, a network cut) the consumer closes that
channel and, on close, restores the messages it still holds (``QoS.restore_unacked_once``); with
Redis still down that restore raises, and its error handling then meets the closed channel (its
transport's ``client`` is None) and raises ``AttributeError: 'NoneType' object has no attribute
'hostname'``, which Celery reports as an "Unrecoverable error": the worker node stops consuming
for good while staying up (``tests/farm/test_farm_faults.py::test_redis_restarted_with_persistence``
caught it in about 1 run of 6 on a loaded machine; upstream: celery/celery#10205). A task that
ends during the outage hits the same path through ``ack`` and ``reject``.

Nothing needs those calls to succeed: a message that could not be acknowledged, rejected or
restored stays in kombu's ``unacked`` hash in Redis, from which any worker restores it after
``visibility_timeout``, and the service's stall rule re-queues the unmerged passes of an idle job
sooner (``services.farm.merge.requeue_stalled``); merging is exactly once, so a pass run twice
counts once. ``install`` wraps the three calls so that a dead connection is logged instead of
raised. It is applied when the worker's Celery app is imported.
"""

from __future__ import annotations

import functools
import logging

import redis
from kombu.transport import redis as kombu_redis

log = logging.getLogger(__name__)

# The errors of a channel whose Redis connection is gone (see the module docstring).
DEAD_CHANNEL = (AttributeError, redis.ConnectionError, redis.TimeoutError)
GUARDED = ("ack", "reject", "restore_unacked")


def _guard(name: str, method):
    @functools.wraps(method)
    def guarded(self, *args, **kwargs):
        try:
            return method(self, *args, **kwargs)
        except DEAD_CHANNEL as err:
            log.warning("kombu %s failed on a lost Redis connection (%r); the message stays in "
                        "Redis' unacked hash and comes back after the visibility timeout or the "
                        "service's stall rule", name, err)
            return None

    guarded.__lucent_guarded__ = True  # type: ignore[attr-defined]
    return guarded


def install(qos_class: type = kombu_redis.QoS) -> None:
    """Wrap ``ack``, ``reject`` and ``restore_unacked`` of kombu's Redis ``QoS`` (idempotent)."""
    for name in GUARDED:
        method = getattr(qos_class, name)
        if not getattr(method, "__lucent_guarded__", False):
            setattr(qos_class, name, _guard(name, method))
