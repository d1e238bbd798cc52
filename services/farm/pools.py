"""Worker pools: tags a worker node offers and a job requires, and the Celery queues between them.

A worker node starts with tags (``lucent worker --tags gpu,bigmem``, ``LUCENT_WORKER_TAGS``); a
job may require tags (``"tags": ["gpu"]`` in ``POST /api/jobs``). A job's passes go to one queue
named by its sorted tags, ``lucent.pool.bigmem,gpu`` (a job without tags: Celery's default queue,
``celery``), and a node consumes the default queue plus the queue of every non-empty subset of its
tags, so it takes exactly the jobs whose tags it has all of. A node has at most ``MAX_WORKER_TAGS``
tags (2^5 - 1 = 31 pool queues, each one Redis list per priority level that the node's ``BRPOP``
watches).

Nothing refuses a job whose tags no live worker has: its passes wait in their queue until one
comes, and its status says so (``waiting_for``). ``check_workers`` in the request asks for a 409
instead.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Iterable

DEFAULT_QUEUE = "celery"
POOL_PREFIX = "lucent.pool."
TAG = re.compile(r"[a-z0-9][a-z0-9_-]{0,31}")
MAX_WORKER_TAGS = 5
MAX_JOB_TAGS = 8


def check_tag(tag: str) -> str:
    """The tag, or ValueError saying what a tag may be."""
    if not isinstance(tag, str) or TAG.fullmatch(tag) is None:
        raise ValueError(f"tag {tag!r} is not 1-32 characters of a-z, 0-9, '_' and '-' starting "
                         "with a letter or digit")
    return tag


def parse_tags(text: str | Iterable[str]) -> tuple[str, ...]:
    """``"gpu, bigmem"`` or ``["gpu", "bigmem"]`` -> ``("bigmem", "gpu")`` (sorted, unique)."""
    items = text.split(",") if isinstance(text, str) else list(text)
    return tuple(sorted({check_tag(t.strip()) for t in items if t.strip()}))


def queue_for(tags: Iterable[str]) -> str:
    """The Celery queue of a job requiring ``tags``."""
    tags = sorted(set(tags))
    return POOL_PREFIX + ",".join(tags) if tags else DEFAULT_QUEUE


def worker_queues(tags: Iterable[str]) -> list[str]:
    """The queues a node with ``tags`` consumes: the default one and one per non-empty subset."""
    tags = sorted(set(tags))
    if len(tags) > MAX_WORKER_TAGS:
        raise ValueError(f"a worker has at most {MAX_WORKER_TAGS} tags (got {len(tags)}: each "
                         "subset is a queue it watches)")
    return [DEFAULT_QUEUE] + [queue_for(subset) for n in range(1, len(tags) + 1)
                              for subset in itertools.combinations(tags, n)]


def has_tags(worker_tags: Iterable[str], job_tags: Iterable[str]) -> bool:
    return set(job_tags) <= set(worker_tags)


def live(workers: list[dict[str, str]]) -> list[dict[str, str]]:
    """The worker processes whose heartbeat has not expired, of ``JobStore.workers``'."""
    return [w for w in workers if w.get("state", "lost") != "lost"]


def live_tag_sets(workers: list[dict[str, str]]) -> list[frozenset[str]]:
    """The tags of each live worker process (``JobStore.workers``' heartbeats)."""
    return [frozenset(t for t in w.get("tags", "").split(",") if t) for w in live(workers)]


def eligible(workers: list[dict[str, str]], job_tags: Iterable[str]) -> list[dict[str, str]]:
    """The live workers (``JobStore.workers``' heartbeats) that take a job requiring
    ``job_tags``: those whose node has them all."""
    return [w for w in live(workers)
            if has_tags((t for t in w.get("tags", "").split(",") if t), job_tags)]


def merge_protocol(workers: list[dict[str, str]], own: int) -> int:
    """The merge protocol every one of ``workers`` (``eligible``'s) keeps
    (``services.farm.store.MERGE_PROTOCOL``; a heartbeat without one is a worker from before
    protocols: 1); ``own`` where there are none (the workers that come are this code's, or are
    refused nothing: see docs/farm.md)."""
    return min((worker_protocol(w) or 1 for w in workers), default=own)


def packet_workers(workers: list[dict[str, str]], own: bool) -> bool:
    """Whether a job's passes are sized for the packet kernel: one of ``workers``
    (``eligible``'s) renders with it, or none of them says its kernel (there are none, or they
    come from before their heartbeats said): then ``own``, what the service's
    ``worker_kernel`` says."""
    kernels = {w["kernel"] for w in workers if w.get("kernel")}
    return "packet" in kernels if kernels else own


def worker_protocol(worker: dict[str, str]) -> int | None:
    """A worker's merge protocol from its heartbeat: 1 where it gives none (from before
    protocols), None where its heartbeat has expired (nothing known of it)."""
    if "pid" not in worker:
        return None
    try:
        return int(worker.get("protocol") or 1)
    except ValueError:
        return 1


def waiting_for(job_tags: Iterable[str], live: list[frozenset[str]]) -> str | None:
    """What a queued or running job requiring ``job_tags`` waits for, when no live worker has
    them all; None when one does (or it requires none)."""
    tags = sorted(job_tags)
    if not tags or any(has_tags(w, tags) for w in live):
        return None
    return f"waiting for a worker with tags {','.join(tags)}"
