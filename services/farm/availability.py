"""Whether the farm can work now, in words a client may see: Redis answering, workers alive.

Redis's own error messages name its host and port (``Error 111 connecting to 10.0.0.5:6379.
Connection refused.``); the probes are open routes, so what they and the API's 503s say is the
kind of failure only (``reason``), and the details go to the service's log.
"""

from __future__ import annotations

import errno
import logging

import redis
from kombu.exceptions import OperationalError

from services.farm.pools import live
from services.farm.store import JobStore

log = logging.getLogger(__name__)

# What means "the store cannot be reached now", as opposed to a bug (a WRONGTYPE reply is a 500).
# AuthenticationError and BusyLoadingError (a restarted Redis reading its append-only file) are
# ConnectionErrors; kombu raises OperationalError when the broker (the same Redis) is unreachable.
UNAVAILABLE = (redis.ConnectionError, redis.TimeoutError, OperationalError)

# Seconds a client is told to wait before it asks again (``Retry-After``): a supervised Redis is
# back within a second or two of dying (services/launcher.py).
RETRY_AFTER = 1


def reason(err: BaseException) -> str:
    """The kind of failure, without host, port or password."""
    if isinstance(err, redis.BusyLoadingError):
        return "Redis is loading its data after a restart"
    if isinstance(err, redis.AuthenticationError):
        return "Redis refused the farm's credentials"
    if isinstance(err, redis.TimeoutError):
        return "Redis did not answer in time"
    cause = err.__cause__ or err.__context__
    code = getattr(cause, "errno", None) or (err.args[0] if err.args and isinstance(
        err.args[0], int) else None)
    text = str(err)
    if code == errno.ECONNREFUSED or "Connection refused" in text:
        return "Redis refused the connection (it is not running)"
    if "Connection closed" in text or code in (errno.ECONNRESET, errno.EPIPE):
        return "Redis closed the connection"
    return "Redis cannot be reached"


def unavailable_detail(err: BaseException) -> str:
    """The ``detail`` of a 503: what is wrong and what to do."""
    log.warning("the store is unavailable: %s: %s", type(err).__name__, err)
    return f"the farm's store is unavailable: {reason(err)}; try again shortly"


def readiness(store: JobStore) -> list[str]:
    """Why the farm cannot render now (empty: ready). Redis must answer, and at least one worker
    process's heartbeat must be live: without one, accepted jobs would wait for nobody."""
    try:
        store.ping()
        workers = store.workers()
    except UNAVAILABLE as err:
        return [unavailable_detail(err)]
    if not live(workers):
        return ["no live workers: no worker process has sent a heartbeat within its timeout"]
    return []
