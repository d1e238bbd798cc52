"""worker/kombu_guard.py: a message call on a channel whose Redis connection is gone is logged,
not raised (the error that stopped a worker node from consuming after a Redis restart), and
nothing else is swallowed. The end-to-end check is test_farm_faults.py's Redis restart."""

from __future__ import annotations

import logging

import pytest
import redis
from kombu.transport import redis as kombu_redis

from worker import kombu_guard


class FakeQoS:
    def __init__(self, error: BaseException | None):
        self.error = error
        self.calls: list[str] = []

    def _call(self, name: str):
        self.calls.append(name)
        if self.error is not None:
            raise self.error
        return name

    def ack(self, delivery_tag):
        return self._call("ack")

    def reject(self, delivery_tag, requeue=False):
        return self._call("reject")

    def restore_unacked(self, client=None):
        return self._call("restore_unacked")


@pytest.fixture
def qos_class():
    class QoS(FakeQoS):
        pass

    kombu_guard.install(QoS)
    kombu_guard.install(QoS)  # idempotent: wrapped once
    return QoS


@pytest.mark.parametrize("error", [
    AttributeError("'NoneType' object has no attribute 'hostname'"),
    redis.ConnectionError("Error 111 connecting to 127.0.0.1:6379. Connection refused."),
    redis.TimeoutError("Timeout reading from socket"),
])
def test_a_dead_connection_is_logged_not_raised(qos_class, error, caplog):
    qos = qos_class(error)
    with caplog.at_level(logging.WARNING, logger="worker.kombu_guard"):
        assert qos.ack("tag") is None
        assert qos.reject("tag", requeue=True) is None
        assert qos.restore_unacked() is None
    assert qos.calls == ["ack", "reject", "restore_unacked"]  # each ran once, not retried
    assert len(caplog.records) == 3
    assert "unacked hash" in caplog.records[0].getMessage()


def test_other_errors_and_results_pass_through(qos_class):
    assert qos_class(None).ack("tag") == "ack"
    with pytest.raises(ValueError):
        qos_class(ValueError("a bug, not a lost connection")).reject("tag")


def test_the_worker_app_guards_kombus_redis_qos():
    import worker.celery_app  # noqa: F401  (installs the guard)

    for name in kombu_guard.GUARDED:
        assert getattr(getattr(kombu_redis.QoS, name), "__lucent_guarded__", False), name
